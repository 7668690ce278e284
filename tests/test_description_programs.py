"""What a description declares for motion programs and digital I/O, on any described drive:
[programs], retarget_absolute (a running move takes a new target), read_completion (a
short read decoded by [status]), terminals by name with their function registers, the
reasons set_output and prepare_table give, and the generic twin's set_input."""

from __future__ import annotations

import textwrap
import tomllib
from collections.abc import AsyncIterator
from contextlib import asynccontextmanager
from pathlib import Path

import anyio
import pytest

from drivebus import LineSettings
from drivebus.drives.base import MoveParams
from drivebus.drives.description import Description, load_description, parse_description
from drivebus.drives.engine import DescribedProfile, profile_class
from drivebus.errors import ConfigError, NotSupported
from drivebus.sim import VirtualWire, sim_bus
from drivebus.sim.described import DescribedDrive, described_twin
from drivebus.sim.drive import TwinSetup

FAST = LineSettings.parse("115200 8N1")
QUICK = MoveParams(600, 20, 20)  # 10 rev/s, 0.5 s ramps

DRIVE = """
[drive]
family = "PROGDRIVE"

[units.pulses_per_rev]
default = 1000

[constants]
START = 1
INTERRUPT = 4
STOP = 8

[registers.status]
address = 0
access = "R"
bits.ENABLED = { bit = 0, means = "enabled" }
bits.MOVING = { bit = 1, means = "moving" }
bits.REACHED = { bit = 2, means = "in_position" }
bits.ALARM = { bit = 3, means = "alarm" }

[registers.alarm_code]
address = 1
access = "R"
means = "alarm_code"

[registers.inputs]
address = 2
access = "R"
means = "inputs"

[registers.outputs]
address = 3
access = "R"
means = "outputs"

[registers.position]
address = 4
words = 2
signed = true
unit = "pulses"
access = "R"
means = "position"

[registers.speed]
address = 0x10
unit = "rpm"
min = 1
max = 3000
default = 60

[registers.accel]
address = 0x11
unit = "r/s²"
min = 1
max = 1000
default = 10

[registers.target]
address = 0x12
words = 2
signed = true
unit = "pulses"

[registers.control]
address = 0x14
volatile = true

[registers.in_function]
address = 0x20
count = 3
defaults = [2, 0, 0]
max = 9

[status]
poll = [["status", "position"]]

[registers.in_level]
address = 0x23
max = 7

[inputs]
state = "inputs"
invert = "in_level"
functions = "in_function"
codes = { limit_positive = 2 }
names = ["IN0", "IN1", "IN2"]
function_names = { 0 = "general purpose", 2 = "positive limit", 9 = "probe" }

[outputs]
state = "outputs"
bits = { alarm = 0, in_position = 1 }
names = ["OUT0", "OUT1"]

[programs]
retarget = "control bit 2 makes a new start take over the running move"

[procedures.move_absolute]
steps = [
  { write = { speed = "speed", accel = "accel", target = "target" }, block = "True" },
  { write = { control = "START" }, idempotent = false },
]

[procedures.retarget_absolute]
steps = [
  { write = { speed = "speed", accel = "accel", target = "target" }, block = "True" },
  { write = { control = "START | INTERRUPT" }, idempotent = false },
]

[status.completion]
read = [["status", "inputs"]]

[procedures.stop]
steps = [{ write = { control = "STOP" } }]

[procedures.set_output]
unsupported = "its outputs follow the alarm and the in-position signal"

[procedures.prepare_table]
unsupported = "it has no position table"

[[twin.on_write]]
register = "control"
when = "value & STOP"
do = "stop"
decel = "accel"

[[twin.on_write]]
register = "control"
when = "value & START and (not moving or value & INTERRUPT)"
do = "move_absolute"
target = "target"
speed = "speed"
accel = "accel"
decel = "accel"
"""


def write(tmp_path: Path, text: str) -> Path:
    p = tmp_path / "drive.toml"
    p.write_text(textwrap.dedent(text), encoding="utf-8")
    return p


D: Description = parse_description(tomllib.loads(DRIVE), "progdrive")
Profile = profile_class(D)
Twin = described_twin(D)


def reads(wire: VirtualWire) -> list[tuple[int, int]]:
    """(first address, count) of the master's FC03 requests."""
    return [(int.from_bytes(f.data[2:4], "big"), int.from_bytes(f.data[4:6], "big"))
            for f in wire.requests() if f.data[1] == 3]


@asynccontextmanager
async def rig(twin: DescribedDrive | None = None
              ) -> AsyncIterator[tuple[DescribedDrive, VirtualWire, DescribedProfile]]:
    twin = twin or Twin(1, FAST)
    async with sim_bus([twin], FAST) as (wire, bus):
        yield twin, wire, Profile(bus.slave(1))  # type: ignore[arg-type]


def test_the_profile_class_declares_what_the_description_says() -> None:
    assert Profile.programs.blends and "control bit 2" in Profile.programs.retarget
    assert not Profile.programs.preload and not Profile.programs.jog_speed
    assert Profile.io_inputs == ("IN0", "IN1", "IN2")
    assert Profile.io_outputs == ("OUT0", "OUT1")
    assert Profile.no_output_control == "its outputs follow the alarm and the in-position signal"
    assert Profile.no_table == "it has no position table"


async def test_a_running_move_takes_a_new_target_without_coming_to_rest() -> None:
    async with rig() as (twin, wire, profile):
        await profile.move_absolute(20_000, QUICK)
        with anyio.fail_after(5):
            while True:  # the twin's counter is the condition; each poll re-reads it
                if twin.position() >= 2_000:
                    break
                await anyio.sleep(0.01)
        await profile.move_absolute(5_000, QUICK)  # without the interrupt bit: ignored
        assert twin.is_moving()
        await profile.retarget_absolute(8_000, QUICK)
        assert wire.requests()[-1].data[1:6] == bytes((6, 0, 0x14, 0, 5))  # START|INTERRUPT
        with anyio.fail_after(10):
            while twin.is_moving():
                assert twin.position() <= 8_000 + 1
                await anyio.sleep(0.01)
        assert twin.position() == 8_000


async def test_read_completion_is_one_short_read_decoded_by_the_status_fields() -> None:
    setup = TwinSetup(limit_positive=3_000)
    async with rig(Twin(1, FAST, setup)) as (twin, wire, profile):
        await profile.learn()
        await profile.move_absolute(2_000, QUICK)
        before = len(reads(wire))
        c = await profile.read_completion()
        assert c is not None and c.moving and not c.in_position and not c.alarm
        assert reads(wire)[before:] == [(0, 3)]  # status, alarm code, inputs
        with anyio.fail_after(10):
            while True:
                c = await profile.read_completion()
                if not c.moving:
                    break
                await anyio.sleep(0.01)
        assert c.in_position and not c.limit_positive
        twin.raise_alarm(7)
        c = await profile.read_completion()
        assert c.alarm and not c.in_position
    without = profile_class(parse_description(
        tomllib.loads(DRIVE.replace("[status.completion]\nread = "
                                                  "[[\"status\", \"inputs\"]]",
                                                  "")), "x"))
    async with sim_bus([Twin(1, FAST)], FAST) as (_, bus):
        assert await without(bus.slave(1)).read_completion() is None  # type: ignore[arg-type]


async def test_io_points_name_each_terminal_and_set_input_drives_one() -> None:
    async with rig() as (twin, wire, profile):
        await profile.slave.write_register(0x21, 9)  # IN1 becomes the probe input
        before = len(reads(wire))
        points = {p.name: p for p in await profile.io_points()}
        assert reads(wire)[before:] == [(0x20, 3)]  # the function table, once
        assert [points[n].function for n in ("IN0", "IN1", "IN2")] == [
            "positive limit", "probe", "general purpose"]
        assert points["OUT0"].output and points["OUT0"].function == "alarm"
        assert points["OUT1"].function == "in position"
        assert not any(p.settable for p in points.values())
        twin.set_input(1, True)
        twin.set_input("in2", True)
        inputs, outputs = profile.io_state(await profile.read_status())
        assert inputs == {"IN0": False, "IN1": True, "IN2": True}
        assert outputs == {"OUT0": False, "OUT1": True}
        twin.set_input("IN1", False)
        inputs, _ = profile.io_state(await profile.read_status())
        assert inputs == {"IN0": False, "IN1": False, "IN2": True}
        # inverted levels: IN0's limit switch (inactive) is a closed normally-closed
        # contact; IN2, closed from outside, still reads closed
        await profile.slave.write_register(0x23, 0b101)
        inputs, _ = profile.io_state(await profile.read_status())
        assert inputs == {"IN0": True, "IN1": False, "IN2": True}
        with pytest.raises(ConfigError, match=r"input 3: .*PROGDRIVE has inputs IN0\.\.IN2"):
            twin.set_input(3, True)
        with pytest.raises(ConfigError, match=r"input 'X1': .*inputs IN0\.\.IN2"):
            twin.set_input("X1", True)
        with pytest.raises(NotSupported, match=r"PROGDRIVE.*follow the alarm"):
            await profile.set_output("OUT0", True)
        with pytest.raises(NotSupported, match=r"PROGDRIVE.*no position table"):
            await profile.prepare_table([], "IN0")


async def test_without_retarget_a_running_move_keeps_its_target_and_says_why() -> None:
    text = DRIVE.replace('[programs]\nretarget = "control bit 2 makes a new start take over '
                         'the running move"\n', '[programs]\nno_retarget = "it ignores a new '
                         'start while it moves"\n')
    i = text.index("[procedures.retarget_absolute]")
    text = text[:i] + text[text.index("[status.completion]"):]
    cls = profile_class(parse_description(tomllib.loads(text), "x"))
    assert not cls.programs.blends
    async with sim_bus([Twin(1, FAST)], FAST) as (wire, bus):
        profile = cls(bus.slave(1))  # type: ignore[arg-type]
        with pytest.raises(NotSupported, match=r"PROGDRIVE.*it ignores a new start"):
            await profile.retarget_absolute(1_000, QUICK)
        assert not wire.requests()


@pytest.mark.parametrize(("mistake", "old", "new", "needles"), [
    ("retarget without procedure", "[procedures.retarget_absolute]",
     "[procedures.retarget_elsewhere]",
     ("programs.retarget", "needs procedures.retarget_absolute")),
    ("names and functions", 'names = ["IN0", "IN1", "IN2"]', 'names = ["IN0", "IN1"]',
     ("inputs.names", "2 terminals, but register in_function assigns 3")),
    ("a name twice", 'names = ["OUT0", "OUT1"]', 'names = ["OUT0", "out0"]',
     ("outputs.names", "named twice")),
    ("function names without functions", 'bits = { alarm = 0, in_position = 1 }',
     'bits = { alarm = 0, in_position = 1 }\nfunction_names = { 1 = "alarm" }',
     ("outputs.function_names", "need 'functions'")),
    ("function code", '9 = "probe"', 'x = "probe"',
     ("inputs.function_names", "not a whole number")),
    ("completion reads an unknown register", 'read = [["status", "inputs"]]',
     'read = [["status", "nowhere"]]',
     ("status.completion.read[0]", "nowhere")),
])
def test_each_programs_or_io_mistake_names_file_and_key(
    tmp_path: Path, mistake: str, old: str, new: str, needles: tuple[str, ...]
) -> None:
    assert old in DRIVE, mistake
    path = write(tmp_path, DRIVE.replace(old, new))
    with pytest.raises(ConfigError) as err:
        load_description(path)
    message = str(err.value)
    assert message.startswith(f"{path}:"), message
    for needle in needles:
        assert needle in message, (needle, message)
