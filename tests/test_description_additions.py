"""The description format's additions for seed drives (the BHSS as data): steps per map
entry, writes of only what differs, a short completion read, programs, named I/O, wired
input terminals with a polarity register, reference-edge homing with a compensation
move, and the twin's value and outside-the-map refusals. Each runs the command engine
against the generic twin on a virtual wire."""

from __future__ import annotations

import textwrap
import tomllib
from collections.abc import AsyncIterator, Callable
from contextlib import asynccontextmanager
from typing import Any

import anyio
import pytest

from drivebus import LineSettings
from drivebus.bus import Bus
from drivebus.clock import monotonic
from drivebus.drives.base import MoveParams
from drivebus.drives.bhss import BHSSProfile
from drivebus.drives.description import parse_description
from drivebus.drives.engine import DescribedProfile, profile_class
from drivebus.drives.registry import builtin_description
from drivebus.drives.status import DriveStatus
from drivebus.errors import ConfigError, ModbusException, NotSupported, UnknownMethod
from drivebus.line import SerialLine
from drivebus.sim import VirtualWire, sim_bus
from drivebus.sim.described import DescribedDrive, twin_of
from drivebus.sim.drive import TwinSetup

FAST = LineSettings.parse("115200 8N1")
QUICK = MoveParams(600, 100, 100)

TERMINALS = """
[drive]
family = "TERMINALS"

[units.pulses_per_rev]
default = 1000

[registers.status]
address = 0
access = "R"
bits.MOVING = { bit = 0, means = "moving" }
bits.REACHED = { bit = 1, means = "reached" }

[registers.inputs]
address = 1
access = "R"
means = "inputs"

[registers.function]
address = 2
count = 3
names = ["IN1", "IN2", "IN3"]
name = "{name} function"
parameter = "{name:lower}_function"
values = { none = 0, limit_positive = 1, limit_negative = 2, home = 3 }
max = 3

[registers.mode]
address = 5
max = 9
valid = "value != 7"

[options.wiring]
type = "map"
keys = ["IN1", "IN2", "IN3"]
choices = ["none", "limit_positive", "limit_negative", "home"]

[status]
moving = "status.MOVING"

[status.completion]
read = ["status"]
moving = "status.MOVING"
in_position = "status.REACHED"

[inputs]
state = "inputs"
functions = "function"
codes = { limit_positive = 1, limit_negative = 2, home_switch = 3 }
names = ["IN1", "IN2", "IN3"]

[programs]
preload = "the manual says so"

[procedures.prepare_table]
unsupported = "it has none"

[homing.methods]
home = { code = 1, behaviour = "reference_edge", reference = "home_switch", direction = 1 }

[procedures.setup]
steps = [
  { read = ["mode", "function"] },
  { write = { mode = 3 }, if_changed = true },
{ write = { "function[k]" = "option.wiring[k]" }, each = "k in option.wiring", if_changed = true },
]

[link]
refusals = { outside = 4 }
"""


@asynccontextmanager
async def rig(text: str, setup: TwinSetup | None = None, **options: Any
              ) -> AsyncIterator[tuple[VirtualWire, DescribedDrive, DescribedProfile]]:
    d = parse_description(tomllib.loads(textwrap.dedent(text)), "test.toml")
    twin = twin_of(d)(1, FAST, setup)
    async with sim_bus([twin], FAST) as (wire, bus):
        yield wire, twin, profile_class(d)(bus.slave(1), **options)


def writes(wire: VirtualWire) -> list[tuple[int, int]]:
    """(address, value) of every FC06 request on the wire."""
    return [(int.from_bytes(f.data[2:4], "big"), int.from_bytes(f.data[4:6], "big"))
            for f in wire.requests() if f.data[1] == 6]


async def test_each_entry_of_a_map_is_written_in_key_order_and_only_where_it_differs() -> None:
    async with rig(TERMINALS, wiring={"IN3": "home", "IN1": "limit_negative"}) as (
            wire, twin, profile):
        await profile.setup()
        # the map's entries in the order of its keys, whatever order the caller gave
        assert writes(wire) == [(5, 3), (2, 2), (4, 3)]
        assert [twin.regs[a] for a in (2, 3, 4, 5)] == [2, 0, 3, 3]
        wire.clear_log()
        await profile.setup()
        assert writes(wire) == []  # everything already holds its value: reads only


async def test_completion_programs_io_names_and_parameter_keys() -> None:
    async with rig(TERMINALS) as (wire, twin, profile):
        assert profile.io_inputs == ("IN1", "IN2", "IN3")
        assert profile.programs.preload == "the manual says so"
        assert profile.no_table == "it has none"
        assert [p.key for p in profile.parameters()][:3] == [
            "in1_function", "in2_function", "in3_function"]
        assert profile.description.regs["function"].at("IN2").name == "IN2 function"
        twin.write_registers(3, [1], 0.0)  # IN2: positive limit
        points = await profile.io_points()
        assert [(p.name, p.function) for p in points] == [
            ("IN1", "none"), ("IN2", "limit positive"), ("IN3", "none")]
        wire.clear_log()
        done = await profile.read_completion()
        assert done is not None and not done.moving and done.in_position  # reached at power-up
        assert [f.data[:6] for f in wire.requests()] == [bytes.fromhex("010300000001")]


async def test_value_and_outside_refusals() -> None:
    async with rig(TERMINALS) as (_wire, _twin, profile):
        with pytest.raises(ModbusException) as err:
            await profile.slave.write_register(5, 7)  # in range, but no mode
        assert err.value.code == 3
        await profile.slave.write_register(5, 8)
        with pytest.raises(ModbusException) as err:
            await profile.slave.read_holding_registers(6, 1)  # past the last register
        assert err.value.code == 4


# -- the BHSS: wired inputs, polarity, reference-edge homing, 'reached' -------------------


BHSS = builtin_description("BHSS")


@asynccontextmanager
async def bhss(setup: TwinSetup, **options: Any
               ) -> AsyncIterator[tuple[VirtualWire, DescribedDrive, DescribedProfile]]:
    twin = twin_of(BHSS)(1, FAST, setup)
    async with sim_bus([twin], FAST) as (wire, bus):
        profile = profile_class(BHSS)(bus.slave(1), **options)
        await profile.setup()
        yield wire, twin, profile


async def wait_for(profile: DescribedProfile, cond: Callable[[DriveStatus], bool],
                   timeout: float = 5.0) -> DriveStatus:
    with anyio.fail_after(timeout):
        while True:
            st = await profile.read_status()
            if cond(st):
                return st
            await anyio.sleep(0.005)


async def test_the_polarity_register_inverts_what_the_drive_acts_on() -> None:
    async with bhss(TwinSetup(limit_positive=2000)) as (_wire, twin, profile):
        st = await profile.read_status()
        assert not st.limit_positive and st.raw["inputs"] == 0
        await profile.slave.write_register(0x0040, 1 << 3)  # X1 (the + limit) inverted
        st = await profile.read_status()
        assert st.limit_positive and st.raw["inputs"] == 1 << 3  # off the switch: active
        await profile.move_relative(500, QUICK)  # towards an active limit: refused
        assert not (await profile.read_status()).moving and twin.position() == 0
        await profile.slave.write_register(0x0040, 0)
        twin.set_input(5, True)  # X3, driven from outside: shown, no function
        st = await profile.read_status()
        assert st.raw["inputs"] == 1 << 5 and not st.limit_positive
        await profile.move_relative(500, QUICK)
        st = await wait_for(profile, lambda s: s.in_position)
        assert st.position == 500


async def test_reference_edge_homing_ends_with_the_compensation_move() -> None:
    async with bhss(TwinSetup(position=-1500, home_switch=0)) as (_wire, twin, profile):
        with pytest.raises(UnknownMethod) as err:
            await profile.home("index")
        assert isinstance(err.value, NotSupported) and isinstance(err.value, ConfigError)
        await profile.home("forward_limit_origin", speed_rpm=600, creep_rpm=60,
                           accel_rps2=100.0, offset=250)
        st = await wait_for(profile, lambda s: s.homed and not s.moving, timeout=10)
        assert st.position == 250 and st.in_position
        assert twin.physical_position() == pytest.approx(250, abs=1)  # edge + offset


async def test_a_stopped_move_has_not_reached_its_position() -> None:
    async with bhss(TwinSetup()) as (_wire, _twin, profile):
        await profile.move_relative(50_000, QUICK)
        await wait_for(profile, lambda s: s.moving)
        await profile.stop()
        st = await wait_for(profile, lambda s: not s.moving)
        assert not st.in_position and not st.raw["status"] & 1
        await profile.move_relative(100, QUICK)
        st = await wait_for(profile, lambda s: s.in_position)
        assert st.raw["status"] & 1


async def test_the_pulse_output_caps_what_the_twin_runs() -> None:
    async with bhss(TwinSetup(), pulses_per_rev=51200) as (_wire, twin, profile):
        # 300 rpm at 51200 pulses/rev would be 256 kHz: the profile refuses it, a raw
        # start shows the drive's 200 kHz cap
        await profile.slave.write_register(0x0023, 300)
        await profile.slave.write_register(0x0027, 2)
        assert twin.velocity(monotonic() + 2.0) == pytest.approx(200_000)
        await profile.emergency_stop()


def test_the_baud_register_applies_at_power_up_where_the_switches_select_it() -> None:
    twin = twin_of(BHSS)(1, LineSettings.parse("128000 8O1"))  # SW6 = SW7 = ON
    assert (twin.regs[0x0014], twin.regs[0x0015]) == (2, 3)
    twin.write_registers(0x0014, [3], 0.0)  # stored: write-through is on
    twin.power_loss()
    twin.power_restore()
    assert twin.settings == LineSettings.parse("256000 8O1")
    twin = twin_of(BHSS)(1, LineSettings.parse("115200 8N1"))  # set by the switches
    twin.write_registers(0x0014, [3], 0.0)
    twin.power_loss()
    twin.power_restore()
    assert twin.settings == LineSettings.parse("115200 8N1")


def test_the_address_register_gives_only_its_addresses() -> None:
    profile = BHSSProfile(Bus(SerialLine("/dev/null", FAST)).slave(1))
    with pytest.raises(NotSupported, match=r"take address 5 from a register.*gives 32-127"):
        profile.comms_writes(5, None, None)
    assert [(r.address, v) for r, v in profile.comms_writes(40, None, None)] == [(0x13, 40)]
