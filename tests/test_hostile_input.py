"""Issue 12: every bad value at a public entry, and every misbehaving peer, is a typed error
naming its cause.

One test per class of bad input: call arguments (Bus, SlaveHandle, the PDU codec), line
settings, drive-profile constructor options, machine files, ports that cannot run the
settings, and peers that misbehave (RTU on a pty, Modbus TCP on loopback). Each asserts the
exact error type and that the message names the cause (parameter or key, and value), and
for bad arguments that nothing reached the wire. The CLI's side is in ``test_cli.py``;
property-based fuzzing of the same entries in ``test_fuzz.py``.
"""

from __future__ import annotations

import asyncio
import inspect
import math
import re
import tomllib
from collections.abc import Awaitable, Callable
from pathlib import Path
from typing import Any

import pytest

from drivebus import Bus, LineSettings, Priority, SerialLine, TcpLine, open_machine
from drivebus.bus import SlaveHandle
from drivebus.config import load_config, parse_config
from drivebus.drives.registry import FAMILIES
from drivebus.errors import (
    ArgumentError,
    ConfigError,
    DrivebusError,
    FrameError,
    LimitViolation,
    LineConfigError,
    LineNoise,
    ModbusException,
    ResponseTimeout,
    WrongResponder,
)
from drivebus.line.rtu import frame
from drivebus.motion.units import Units
from drivebus.sim import RegisterSlave, VirtualWire, lookup_wire, sim_bus
from peers import MakeReply, TcpPeer, mbap, pty_bus, values_pdu

FAST = LineSettings.parse("115200 8N1")

Call = Callable[[SlaveHandle], Awaitable[object]]

BAD_CALLS: list[tuple[str, Call, tuple[str, ...]]] = [
    ("fractional value", lambda s: s.write_register(0, 1.5), ("register value", "1.5")),
    ("negative value", lambda s: s.write_register(0, -1), ("register value", "-1", "0..65535")),
    ("value above a word", lambda s: s.write_register(0, 65536), ("register value", "65536")),
    ("bool value", lambda s: s.write_register(0, True), ("register value", "True")),
    ("NaN value", lambda s: s.write_register(0, math.nan), ("register value", "nan")),
    ("string value", lambda s: s.write_register(0, "7"), ("register value", "'7'")),
    ("negative address", lambda s: s.read_holding_registers(-1, 1), ("register address", "-1")),
    ("address above 65535", lambda s: s.write_register(65536, 0), ("register address", "65536")),
    ("fractional address", lambda s: s.read_input_registers(2.5, 1), ("register address", "2.5")),
    ("infinite address", lambda s: s.read_holding_registers(math.inf, 1),
     ("register address", "inf")),
    ("zero count", lambda s: s.read_holding_registers(0, 0), ("register count", "0", "1..125")),
    ("count above 125", lambda s: s.read_input_registers(0, 126), ("register count", "126")),
    ("fractional count", lambda s: s.read_holding_registers(0, 1.5), ("register count", "1.5")),
    ("span past 65535", lambda s: s.read_holding_registers(65535, 2), ("65535..65536",)),
    ("no values", lambda s: s.write_registers(0, []), ("register values", "0 values", "1..123")),
    ("124 values", lambda s: s.write_registers(0, [0] * 124), ("register values", "124")),
    ("a bad word among values", lambda s: s.write_registers(0, [1, 2, -3]),
     ("register values[2]", "-3")),
    ("values not a sequence", lambda s: s.write_registers(0, 5), ("register values", "5")),
    ("values as a string", lambda s: s.write_registers(0, "ab"), ("register values", "'ab'")),
    ("unknown priority", lambda s: s.read_holding_registers(0, 1, priority=7),
     ("priority", "7", "EMERGENCY")),
    ("priority as text", lambda s: s.write_register(0, 1, priority="high"),
     ("priority", "'high'")),
    ("empty PDU", lambda s: s.transact(b""), ("pdu", "b''")),
    ("PDU too long", lambda s: s.transact(bytes(254)), ("pdu", "1..253")),
    ("PDU not bytes", lambda s: s.transact("03 00 00"), ("pdu", "'03 00 00'")),
    ("expect not callable", lambda s: s.transact(b"\x03\x00\x00\x00\x01", expect=5),  # type: ignore[arg-type]
     ("expect", "5")),
]


@pytest.mark.parametrize(("what", "call", "needles"), BAD_CALLS, ids=[c[0] for c in BAD_CALLS])
async def test_bad_register_call_arguments_are_argument_errors(
    what: str, call: Call, needles: tuple[str, ...]
) -> None:
    """The call fails with ArgumentError naming parameter and value; nothing is queued or
    sent, and the bus goes on serving."""
    slave = RegisterSlave(1, FAST, initial=[(0, 42)])
    async with sim_bus([slave], FAST) as (wire, bus):
        with pytest.raises(ArgumentError) as info:
            await call(bus.slave(1))
        for n in needles:
            assert n in str(info.value), (what, str(info.value))
        assert wire.request_count == 0 and bus.stats.transactions == 0
        assert await bus.slave(1).read_holding_registers(0, 1) == [42]
        assert slave.writes == []


BAD_SLAVES: list[tuple[str, dict[str, Any], tuple[str, ...]]] = [
    ("address above 247", {"address": 300}, ("slave address", "300", "0..247")),
    ("negative address", {"address": -1}, ("slave address", "-1")),
    ("fractional address", {"address": 1.5}, ("slave address", "1.5")),
    ("bool address", {"address": True}, ("slave address", "True")),
    ("NaN timeout", {"timeout": math.nan}, ("response timeout", "nan")),
    ("zero timeout", {"timeout": 0}, ("response timeout", "> 0")),
    ("infinite timeout", {"timeout": math.inf}, ("response timeout", "inf")),
    ("timeout above 10 s", {"timeout": 11.0}, ("response timeout", "11.0", "10 s")),
    ("negative retries", {"retries": -1}, ("retries", "-1", "0..10")),
    ("fractional retries", {"retries": 1.5}, ("retries", "1.5")),
    ("settings as text", {"settings": "9600 8N1"}, ("settings", "'9600 8N1'", "LineSettings")),
]


@pytest.mark.parametrize(("what", "kwargs", "needles"), BAD_SLAVES,
                         ids=[c[0] for c in BAD_SLAVES])
async def test_bad_slave_settings_are_config_errors(
    what: str, kwargs: dict[str, Any], needles: tuple[str, ...]
) -> None:
    async with sim_bus([RegisterSlave(1, FAST)], FAST) as (wire, bus):
        args = {"address": 1, **kwargs}
        with pytest.raises(ConfigError) as info:
            bus.slave(args.pop("address"), **args)
        for n in needles:
            assert n in str(info.value), (what, str(info.value))
        assert wire.request_count == 0


@pytest.mark.parametrize(
    ("kwargs", "needles"),
    [
        ({"timeout": math.nan}, ("response timeout", "nan")),
        ({"timeout": -0.1}, ("response timeout", "-0.1")),
        ({"retries": 11}, ("retries", "11", "0..10")),
        ({"retries": "2"}, ("retries", "'2'")),
    ],
)
def test_bad_bus_settings_are_config_errors(
    kwargs: dict[str, Any], needles: tuple[str, ...]
) -> None:
    with pytest.raises(ConfigError) as info:
        Bus(SerialLine("sim://unused", FAST), **kwargs)
    for n in needles:
        assert n in str(info.value)


def test_priority_accepts_the_enum_and_its_values() -> None:
    """Only the four priorities are valid; ints that name one are accepted."""
    from drivebus.checks import member

    assert member("priority", 3, Priority) is Priority.EMERGENCY
    assert member("priority", Priority.POLL, Priority) is Priority.POLL
    with pytest.raises(ArgumentError, match=r"priority: expected one of POLL \(0\)"):
        member("priority", 4, Priority)


# -- drive profiles: what each declares it accepts ---------------------------------------------

PROFILES = {f.name: f.profile for f in FAMILIES.values()}


def _handle(address: int = 1) -> SlaveHandle:
    """A slave handle on a bus that is never opened (constructors do no I/O)."""
    return Bus(SerialLine("sim://unused", FAST)).slave(address)


@pytest.mark.parametrize("name", sorted(PROFILES))
def test_each_profile_declares_exactly_its_constructor_options(name: str) -> None:
    """The options declaration and the constructor's keyword options are the same set, so
    a machine file is checked against what the constructor really takes."""
    cls = PROFILES[name]
    params = inspect.signature(cls.__init__).parameters
    keywords = {p for p, v in params.items() if v.kind is inspect.Parameter.KEYWORD_ONLY}
    assert set(cls.options.model_fields) == keywords - {"pulses_per_rev"}
    assert cls.line_kinds and cls.line_kinds <= {"serial", "tcp", "rtu-over-tcp"}
    assert cls.pulses_per_rev_problem(4000 if name != "OD2000" else 10000) is None


BAD_OPTIONS: list[tuple[str, dict[str, Any], tuple[str, ...]]] = [
    ("NT86", {"enable_input": 7}, ("enable_input", "7", "less than or equal to 6")),
    ("NT86", {"estop_decel_rps2": math.nan}, ("estop_decel_rps2", "nan", "finite")),
    ("NT86", {"estop_decel_rps2": 5.0}, ("estop_decel_rps2", "5.0", "10")),
    ("NT86", {"enable_input": 3, "clear_alarm_input": 3}, ("clear_alarm_input", "IN3")),
    ("NT86", {"home_offset_moves": "yes"}, ("home_offset_moves", "'yes'", "boolean")),
    ("EPR60", {"home_input": 0}, ("home_input", "0", "greater than or equal to 1")),
    ("EPR60", {"home_input": 5, "enable_input": 5}, ("home_input", "enable_input", "IN5")),
    ("BHSS", {"start_speed_rpm": 301}, ("start_speed_rpm", "301", "300")),
    ("BHSS", {"inputs": {"X9": "origin"}}, ("inputs.X9", "'X9'", "'X0'")),
    ("BHSS", {"inputs": {"X0": "orign"}}, ("inputs.X0", "'orign'", "'origin'")),
    ("CL86R", {"start_speed_rpm": 1}, ("start_speed_rpm", "(got 1)", "2")),
    ("CL86R", {"block_writes": 1}, ("block_writes", "(got 1)", "boolean")),
]


@pytest.mark.parametrize(("drive", "options", "needles"), BAD_OPTIONS,
                         ids=[f"{d}-{'-'.join(o)}" for d, o, _ in BAD_OPTIONS])
def test_bad_profile_options_are_config_errors(
    drive: str, options: dict[str, Any], needles: tuple[str, ...]
) -> None:
    """The constructor refuses them with ConfigError naming drive, option, value and range."""
    with pytest.raises(ConfigError) as info:
        PROFILES[drive](_handle(), **options)
    text = str(info.value)
    assert text.startswith(f"{drive} drive options: ")
    for n in needles:
        assert n in text, text


@pytest.mark.parametrize(
    ("drive", "pulses", "allowed"),
    [("NT86", 100, "200..65535"), ("EPR60", 70000, "200..65535"), ("BHSS", 1234, "400, 800"),
     ("CL86R", 200, "400..51200"), ("OD2000", 1000, "6400..51200"), ("NT86", 4000.5, "200")],
)
def test_pulses_per_rev_a_drive_cannot_run_is_a_config_error(
    drive: str, pulses: float, allowed: str
) -> None:
    with pytest.raises(ConfigError) as info:
        PROFILES[drive](_handle(), pulses_per_rev=pulses)  # type: ignore[arg-type]
    text = str(info.value)
    assert text.startswith("pulses_per_rev: ") and repr(pulses) in text and allowed in text


@pytest.mark.parametrize(
    ("drive", "settings", "needle"),
    [("NT86", "19200 8E1", "cannot talk 8E1 (it talks 8N1)"),
     ("NT86", "57600 8N1", "cannot run 57600 baud"),
     ("BHSS", "12345 8N1", "cannot run 12345 baud"),
     ("BHSS", "19200 7E1", "cannot talk 7E1"),
     ("CL86R", "9600 8E1", "8N1 only at 9600 baud"),
     ("CL86R", "57600 8N1", "cannot run 57600 baud (it runs 9600, 19200, 38400, 115200)"),
     ("OD2000", "19200 8N1", "cannot run 19200 baud (it runs 9600)")],
)
def test_line_settings_a_drive_cannot_do_are_named(drive: str, settings: str, needle: str) -> None:
    assert needle in (PROFILES[drive].settings_problem(LineSettings.parse(settings)) or "")


@pytest.mark.parametrize(
    ("drive", "settings"),
    [("NT86", "115200 8N1"), ("BHSS", "128000 8O1"), ("CL86R", "38400 8N2"),
     ("CL86R", "9600 8N1"), ("OD2000", "9600 8N1")],
)
def test_line_settings_a_drive_can_do_pass(drive: str, settings: str) -> None:
    assert PROFILES[drive].settings_problem(LineSettings.parse(settings)) is None


# -- machine files -------------------------------------------------------------------------------

DEMO = Path(__file__).resolve().parents[1] / "configs" / "demo.toml"
SINGLE = DEMO.with_name("single.toml")


def _demo() -> dict[str, Any]:
    return tomllib.loads(DEMO.read_text())


def _set(path: str, value: object) -> Callable[[dict[str, Any]], None]:
    """A change to the demo machine: ``value`` at dotted ``path``."""

    def change(d: dict[str, Any]) -> None:
        *parents, last = path.split(".")
        for p in parents:
            d = d.setdefault(p, {})
        d[last] = value

    return change


BAD_FILES: list[tuple[str, Callable[[dict[str, Any]], None], tuple[str, ...]]] = [
    ("NaN units_per_rev", _set("axes.x.units_per_rev", math.nan),
     ("axes.x.units_per_rev", "finite", "nan")),
    ("NaN soft limit", _set("axes.x.limits", [math.nan, 10.0]), ("axes.x.limits[0]", "nan")),
    ("infinite speed", _set("axes.y.speed", math.inf), ("axes.y.speed", "inf")),
    ("NaN homing offset", _set("axes.z.homing.offset", math.nan), ("axes.z.homing.offset", "nan")),
    ("NaN poll period", _set("axes.x.poll.moving", math.nan), ("axes.x.poll.moving", "nan")),
    ("infinite sim position", _set("axes.x.sim.position", -math.inf),
     ("axes.x.sim.position", "-inf")),
    ("NaN line timeout", _set("lines.rs485.timeout", math.nan), ("lines.rs485.timeout", "nan")),
    ("NaN in a sim option", _set("axes.x.sim.options", {"hard_stop_positive": math.nan}),
     ("axes.x.sim.options", "hard_stop_positive", "nan")),
    ("NaN drive option", _set("axes.x.drive_options", {"estop_decel_rps2": math.nan}),
     ("axes.x.drive_options.estop_decel_rps2", "nan")),
    ("bool address", _set("axes.x.address", True), ("axes.x.address", "True")),
    ("text speed", _set("axes.x.speed", "fast"), ("axes.x.speed", "'fast'")),
    ("misspelt key", _set("axes.x.spede", 3.0), ("axes.x.spede", "unknown key", "speed")),
    ("two lines on one sim name", _set("lines.eth.host", "sim://demo-rs485"),
     ("lines.eth.host", "sim://demo-rs485", "already line rs485")),
    ("two serial lines on one port",
     _set("lines.second", {"port": "sim://demo-rs485", "settings": "9600 8N1"}),
     ("lines.second.port", "sim://demo-rs485", "already line rs485")),
    ("two lines on one real port",
     lambda d: d["lines"].update(a={"port": "/dev/ttyUSB0"}, b={"port": "/dev/../dev/ttyUSB0"}),
     ("lines.b.port", "serial port /dev/../dev/ttyUSB0 is already line a")),
    ("two lines on one serial server",
     lambda d: d["lines"].update(
         a={"kind": "rtu-over-tcp", "host": "10.0.0.9", "tcp_port": 4001},
         b={"kind": "rtu-over-tcp", "host": "10.0.0.9", "tcp_port": 4001}),
     ("lines.b.host", "serial server 10.0.0.9:4001 is already line a")),
    ("NT86 at 8E1", _set("axes.x.settings", "115200 8E1"),
     ("axes.x.settings", "115200 8E1", "NT86", "8N1")),
    ("CL86R at 12345 baud", _set("axes.z.settings", "12345 8N2"),
     ("axes.z.settings", "12345", "9600, 19200, 38400, 115200")),
    ("OD2000 at 19200", _set("axes.aux.settings", "19200 8N1"), ("axes.aux.settings", "9600")),
    ("BHSS on the line default 7E1", _set("axes.y.settings", "19200 7E1"),
     ("axes.y.settings", "7E1", "8N1, 8N2, 8E1, 8O1")),
    ("NT86 address 40", _set("axes.x.address", 40), ("axes.x.address", "1..31", "40")),
    ("EPR60 on the RS-485 line", _set("axes.r.line", "rs485"),
     ("axes.r.line", "EPR60", "serial line")),
    ("misspelt homing method", _set("axes.x.homing.method", "home_switch_postive"),
     ("axes.x.homing.method", "'home_switch_postive'", "home_switch_positive")),
    ("homing an OD2000", _set("axes.aux.homing", {"method": "limit_negative"}),
     ("axes.aux.homing.method", "cannot home")),
    ("misspelt drive option", _set("axes.r.drive_options", {"home_inptu": 5}),
     ("axes.r.drive_options.home_inptu", "unknown key", "5", "home_input")),
    ("drive option out of range", _set("axes.r.drive_options", {"home_input": 9}),
     ("axes.r.drive_options.home_input", "9", "6")),
    ("pulses/rev the BHSS lacks", _set("axes.y.pulses_per_rev", 1234),
     ("axes.y.pulses_per_rev", "1234", "51200")),
    ("speed above max_speed", _set("axes.x.max_speed", 100.0),
     ("axes.x.speed", "200", "max_speed 100")),
    ("sim switches crossed", _set("axes.y.sim.limit_negative", 300.0),
     ("axes.y.sim.limit_negative", "300", "limit_positive 210")),
    ("soft limits beyond the sim switch", _set("axes.x.sim.limit_positive", -20.0),
     ("axes.x.sim.limit_positive", "-20", "-5..400")),
    ("sim position beyond 32 bits", _set("axes.x.sim.position", 1e12),
     ("axes.x.sim.position", "1e+12", "32-bit")),
    ("unknown twin option", _set("axes.z.sim.options", {"bogus": 1}),
     ("axes.z.sim.options.bogus", "CL86R")),
    ("per-slave settings on a serial server",
     _set("lines.rs485", {"kind": "rtu-over-tcp", "host": "sim://demo-rs485",
                          "settings": "115200 8N1"}),
     ("axes.y.settings", "19200 8E1", "one setting")),
    ("sim:// without a name", _set("lines.rs485.port", "sim://"), ("lines.rs485", "sim://NAME")),
]


@pytest.mark.parametrize(("what", "change", "needles"), BAD_FILES, ids=[b[0] for b in BAD_FILES])
def test_bad_machine_files_are_one_config_error(
    what: str, change: Callable[[dict[str, Any]], None], needles: tuple[str, ...]
) -> None:
    """One ConfigError naming the file and the key path, with the value and what is allowed."""
    data = _demo()
    change(data)
    with pytest.raises(ConfigError) as info:
        parse_config(data, "demo.toml")
    text = str(info.value)
    assert text.startswith("demo.toml: ")
    for n in needles:
        assert n in text, text


def test_a_nan_in_a_toml_file_is_refused_when_loaded(tmp_path: Path) -> None:
    """TOML spells NaN and infinity ``nan``/``inf``: refused by load_config (what
    open_machine and ``drivebus check`` both run), naming file, key and value."""
    f = tmp_path / "m.toml"
    f.write_text(DEMO.read_text().replace("units_per_rev = 10.0", "units_per_rev = nan"))
    with pytest.raises(ConfigError, match=rf"{re.escape(str(f))}: axes\.x\.units_per_rev: .*nan"):
        load_config(f)


async def test_open_machine_refuses_a_bad_file_before_opening_anything(tmp_path: Path) -> None:
    f = tmp_path / "m.toml"
    f.write_text(DEMO.read_text().replace('host = "sim://demo-eth"', 'host = "sim://demo-rs485"'))
    with pytest.raises(ConfigError, match=r"lines\.eth\.host: sim://demo-rs485 is already"):
        async with open_machine(f):
            pytest.fail("opened")
    with pytest.raises(KeyError):
        lookup_wire("demo-rs485")  # no simulator was started


async def test_a_simulator_name_in_use_is_a_config_error() -> None:
    """Two machines (or a machine and a test wire) on one sim:// name in one process."""
    async with VirtualWire("hostile-taken"):
        cfg = parse_config({
            "lines": {"l": {"port": "sim://hostile-taken", "settings": "115200 8N1"}},
            "axes": {"x": {"line": "l", "address": 1, "drive": "CL86R", "pulses_per_rev": 1000}},
        })
        with pytest.raises(ConfigError, match=r"sim://hostile-taken: .*already running"):
            async with open_machine(cfg):
                pytest.fail("opened")


async def test_a_twin_that_refuses_its_options_names_the_axis() -> None:
    """A value only the simulated drive can judge fails at start-up naming axis and key."""
    cfg = parse_config({
        "lines": {"l": {"port": "sim://hostile-twin", "settings": "115200 8N1"}},
        "axes": {"x": {"line": "l", "address": 1, "drive": "NT86", "pulses_per_rev": 4000,
                       "settings": "115200 8N1", "sim": {"options": {"home_cam": "sideways"}}}},
    })
    with pytest.raises(ConfigError, match=r"axes\.x\.sim: the simulated NT86 .*'sideways'"):
        async with open_machine(cfg):
            pytest.fail("opened")


async def test_open_machine_takes_a_mapping_and_refuses_anything_else() -> None:
    """The mapping form is validated like a file; other types, and group names that are
    not axes, are ConfigErrors too (no TypeError from deep inside)."""
    data = tomllib.loads(SINGLE.read_text())
    data["lines"]["bus"]["port"] = "sim://hostile-mapping"
    async with open_machine(data) as m:
        with pytest.raises(ConfigError, match=r"no axis 5, 'q' \(axes: x\)"):
            m.group(5, "q")  # type: ignore[arg-type]
    data["axes"]["x"]["speed"] = -1.0
    with pytest.raises(ConfigError, match=r"^config: axes\.x\.speed: .*\(got -1\.0\)"):
        async with open_machine(data):
            pytest.fail("opened")
    with pytest.raises(ConfigError, match="a machine file is a path, not 5"):
        async with open_machine(5):  # type: ignore[arg-type]
            pytest.fail("opened")


def test_positions_too_far_for_any_drive_are_limit_violations() -> None:
    """A finite target so far out that its pulse count overflows: typed, not OverflowError."""
    u = Units(pulses_per_rev=1000, units_per_rev=0.001)
    with pytest.raises(LimitViolation, match=r"1e\+307 units is inf pulses"):
        u.to_pulses(1e307)
    assert u.to_pulses(1.5) == 1_500_000


# -- baud rates and formats a port cannot run -----------------------------------------------------

ODD = LineSettings.parse("12345 8N1")


async def test_a_non_standard_baud_rate_works_end_to_end_on_a_pty() -> None:
    """pyserial sets 12345 baud on a pty (termios2, BOTHER); the wire observes the rate the
    port really runs, and a slave at 12345 baud answers, with the silences of that rate."""
    slave = RegisterSlave(1, ODD, initial=[(0, 7)])
    async with sim_bus([slave], ODD, timeout=0.5) as (wire, bus):
        assert await bus.slave(1).read_holding_registers(0, 1) == [7]
        assert {f.settings for f in wire.log} == {ODD} and wire.violations == 0
    async with VirtualWire("hostile-plain-pty") as wire:  # the pty path itself, no sim://
        wire.attach(RegisterSlave(1, ODD, initial=[(0, 9)]))
        async with Bus(SerialLine(wire.slave_path, ODD), timeout=0.5) as bus:
            assert await bus.slave(1).read_holding_registers(0, 1) == [9]


async def test_a_rate_the_adapter_cannot_run_is_a_config_error_naming_rate_and_port() -> None:
    """An adapter whose driver substitutes the nearest rate it can make: opening the line
    at 12345 baud fails at once with ConfigError (not a ResponseTimeout later)."""
    async with VirtualWire("hostile-std", adapter_bauds=(9600, 19200, 38400, 115200)) as wire:
        wire.attach(RegisterSlave(1, ODD))
        with pytest.raises(ConfigError) as info:
            async with Bus(SerialLine(wire.url, ODD)):
                pytest.fail("opened")
        text = str(info.value)
        assert "'sim://hostile-std' cannot run 12345 8N1" in text and "set 9600 baud" in text
        assert wire.request_count == 0


async def test_a_per_slave_rate_the_adapter_cannot_run_fails_that_request_only() -> None:
    """The request fails with LineConfigError naming slave, rate and port; the line goes on
    at its previous settings for the other slaves."""
    fast = RegisterSlave(2, FAST, initial=[(0, 5)])
    async with VirtualWire("hostile-mixed", adapter_bauds=(9600, 115200)) as wire:
        wire.attach(RegisterSlave(1, ODD))
        wire.attach(fast)
        async with Bus(SerialLine(wire.url, FAST), timeout=0.2, retries=2) as bus:
            with pytest.raises(LineConfigError) as info:
                await bus.slave(1, settings=ODD).read_holding_registers(0, 1)
            assert "slave 1:" in str(info.value) and "cannot run 12345 8N1" in str(info.value)
            assert isinstance(info.value, ConfigError) and bus.stats.slave(1).retries == 0
            assert await bus.slave(2).read_holding_registers(0, 1) == [5]
            assert {f.settings for f in wire.requests()} == {FAST}


async def test_a_format_the_port_refuses_is_a_config_error_not_a_termios_error() -> None:
    """Ports (and some kernels' ptys) refuse parity with EINVAL from tcsetattr: no raw
    termios.error, but ConfigError at open and LineConfigError for a per-slave setting."""
    even = LineSettings.parse("19200 8E1")
    async with VirtualWire("hostile-no-parity", adapter_formats=("8N1", "8N2")) as wire:
        wire.attach(RegisterSlave(1, FAST, initial=[(0, 3)]))
        with pytest.raises(ConfigError, match=r"cannot run 19200 8E1 \(.*Invalid argument"):
            async with Bus(SerialLine(wire.url, even)):
                pytest.fail("opened")
        async with Bus(SerialLine(wire.url, FAST)) as bus:
            with pytest.raises(LineConfigError, match=r"slave 4: .* cannot run 19200 8E1"):
                await bus.slave(4, settings=even).read_holding_registers(0, 1)
            assert await bus.slave(1).read_holding_registers(0, 1) == [3]


# -- hostile peers ---------------------------------------------------------------------------------

GOOD = values_pdu([1, 2])

RTU_PEERS: list[tuple[str, list[bytes], type[DrivebusError], tuple[str, ...]]] = [
    ("silence", [], ResponseTimeout, ("slave 1 on ", "no reply")),
    ("truncated reply", [frame(1, GOOD)[:5]], FrameError, ("slave 1", "unusable reply")),
    ("bad CRC", [frame(1, GOOD)[:-1] + b"\x00"], FrameError, ("slave 1", "bad CRC")),
    ("wrong function", [frame(1, b"\x04" + GOOD[1:])], FrameError,
     ("slave 1", "reply function 0x04 to request 0x03")),
    ("exception", [frame(1, b"\x83\x02")], ModbusException,
     ("slave 1", "exception 0x02: illegal data address")),
    ("another address", [frame(5, GOOD)], WrongResponder, ("slave 1", "from address 5")),
    ("too many registers", [frame(1, values_pdu([1, 2, 3]))], FrameError,
     ("slave 1", "carries 6 bytes, 4 expected")),
    ("garbage", [b"\xff\x00\x55" * 5], FrameError, ("slave 1", "ff 00 55")),
]


@pytest.mark.parametrize(("what", "script", "error", "needles"), RTU_PEERS,
                         ids=[p[0] for p in RTU_PEERS])
async def test_a_misbehaving_rtu_peer_is_a_typed_error_naming_it(
    what: str, script: list[bytes], error: type[DrivebusError], needles: tuple[str, ...]
) -> None:
    """Over the real serial stack on a pty; then a proper reply is read correctly."""
    async with pty_bus([*script, frame(1, GOOD)] if script else []) as bus:
        with pytest.raises(error) as info:
            await bus.slave(1).read_holding_registers(0, 2)
        assert type(info.value) is error and info.value.slave == 1
        for n in needles:
            assert n in str(info.value), str(info.value)
        if script:
            assert await bus.slave(1).read_holding_registers(0, 2) == [1, 2]


TCP_PEERS: list[tuple[str, MakeReply, type[DrivebusError], tuple[str, ...]]] = [
    ("silence", lambda tid: b"", ResponseTimeout, ("slave 1", "no reply within 50 ms")),
    ("wrong transaction id", lambda tid: mbap(tid ^ 7, GOOD), FrameError,
     ("matches no request", "reply rejected")),
    ("wrong protocol id", lambda tid: mbap(tid, GOOD, protocol=1), LineNoise,
     ("not a Modbus TCP header", "reconnecting")),
    ("length out of range", lambda tid: mbap(tid, GOOD, length=300), LineNoise,
     ("not a Modbus TCP header", "01 2c")),
    ("another unit", lambda tid: mbap(tid, GOOD, unit=5), WrongResponder,
     ("slave 1", "came from unit 5")),
    ("exception", lambda tid: mbap(tid, b"\x83\x02"), ModbusException,
     ("slave 1", "illegal data address")),
    ("too many registers", lambda tid: mbap(tid, values_pdu([1, 2, 3])), FrameError,
     ("slave 1", "carries 6 bytes, 4 expected")),
]


@pytest.mark.parametrize(("what", "make", "error", "needles"), TCP_PEERS,
                         ids=[p[0] for p in TCP_PEERS])
async def test_a_misbehaving_tcp_peer_is_a_typed_error_naming_it(
    what: str, make: MakeReply, error: type[DrivebusError], needles: tuple[str, ...]
) -> None:
    """Over a real loopback connection; then the line works again (reconnecting if the
    stream was out of step)."""
    peer = TcpPeer(make, [1, 2])
    server = await asyncio.start_server(peer.serve, "127.0.0.1", 0)
    try:
        line = TcpLine("127.0.0.1", server.sockets[0].getsockname()[1], reconnect_delay=0.0)
        async with Bus(line, timeout=0.05, retries=0) as bus:
            with pytest.raises(error) as info:
                await bus.slave(1).read_holding_registers(0, 2)
            assert type(info.value) is error
            for n in needles:
                assert n in str(info.value), str(info.value)
            assert await bus.slave(1, retries=2).read_holding_registers(0, 2) == [1, 2]
    finally:
        server.close()
        await server.wait_closed()
