"""Issue 12: every bad value at a public entry is a typed error naming its cause.

One test per class of bad input: call arguments (Bus, SlaveHandle, the PDU codec), line
settings, drive-profile constructor options, machine files. Each asserts the exact error
type, that the message names the parameter (or key) and the value, and that nothing
reached the wire. The CLI's side is in ``test_cli.py``; property-based fuzzing of the same
entries in ``test_fuzz.py``.
"""

from __future__ import annotations

import inspect
import math
from collections.abc import Awaitable, Callable
from typing import Any

import pytest

from drivebus import Bus, LineSettings, Priority
from drivebus.bus import SlaveHandle
from drivebus.drives.registry import FAMILIES
from drivebus.errors import ArgumentError, ConfigError
from drivebus.sim import RegisterSlave, sim_bus

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
    from drivebus import SerialLine

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
    from drivebus import SerialLine

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
