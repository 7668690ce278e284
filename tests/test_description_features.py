"""The description features the NT-family descriptions brought (issue 22): ``extends``,
list options and option checks, ``if_changed`` and ``each`` writes, I/O names and
function names with ``set_output``, homing switches on the options, the dry run past
reads, ``UnknownMethod`` — each on the generic twin of a small description, on the wire."""

from __future__ import annotations

import textwrap
from collections.abc import AsyncIterator
from contextlib import asynccontextmanager
from pathlib import Path

import pytest

from drivebus import LineSettings
from drivebus.drives.description import Description, load_description
from drivebus.drives.engine import DescribedProfile, profile_class
from drivebus.errors import ConfigError, LimitViolation, NotSupported, UnknownMethod
from drivebus.sim import VirtualWire, sim_bus
from drivebus.sim.described import described_twin

FAST = LineSettings.parse("115200 8N1")

BASE = """
[drive]
family = "FEATURES"

[constants]
FUNC_GENERAL = 0
POLARITY = 0x10

[state]
out1 = 0

[units.pulses_per_rev]
default = 1000

[options.outputs]
type = "list"
min = 1
max = 2
max_items = 2
default = []

[options.home_input]
type = "int"
min = 1
max = 2

[options.stop_input]
type = "int"
min = 1
max = 2

[options.reverse]
type = "bool"
default = false

[[option_checks]]
check = "option.home_input is None or option.home_input != option.stop_input"
message = "home_input and stop_input are both X{option.home_input}"

[registers.status]
address = 0
access = "R"
bits.MOVING = { bit = 0, means = "moving" }

[registers.outputs]
address = 1
access = "R"
means = "outputs"

[registers.out_setting]
address = 10
count = 2
first = 1
defaults = [3, 0]
max = 0x1F
name = "Y{n} setting"

[registers.out_values]
address = 12
max = 3

[registers.speed]
address = 20
unit = "rpm"
max = 3000

[registers.points]
address = 30
count = 4
first = 1
max = 1000
name = "point {n}"

[registers.extra]
address = 40

[registers.spare]
address = 41

[registers.copied]
address = 42

[status]
moving = "status.MOVING"

[outputs]
state = "outputs"
functions = "out_setting"
function_mask = 0x0F
settable = 0
names = ["Y1", "Y2"]
function_names = { 0 = "general purpose", 3 = "alarm" }

[homing.methods]
switch_up = { code = 0, reverses_at = "[1] if option.reverse else []" }

[[procedures.setup.steps]]
read = ["out_setting[1]"]
when = "1 in option.outputs"

[[procedures.setup.steps]]
set = { out1 = "out_setting[1] & POLARITY" }
when = "1 in option.outputs"

[[procedures.setup.steps]]
write = { "out_setting[1]" = "state.out1 | FUNC_GENERAL" }
when = "1 in option.outputs"
if_changed = true
volatile = true

[procedures.fill]
params = ["values"]

[[procedures.fill.steps]]
write = { "points[k]" = "values[k - 1]" }
each = "k in range(1, len(values) + 1)"
block = true

[procedures.run_at]
params = ["rpm"]
steps = [{ read = ["status"] }, { write = { speed = "rpm" } }]

[procedures.copy_points]
doc = "a register read in the procedure, written as it is (JVL's P_SOLL = P_IST)"
steps = [{ read = ["extra"] }, { write = { copied = "extra" } }]

[procedures.home]
steps = [{ write = { extra = "home.code" } }]

[procedures.set_output]
params = ["output", "index", "state"]
doc = "an output follows out_values only with function 0"

[[procedures.set_output.steps]]
read = ["out_setting[index]"]

[[procedures.set_output.steps]]
fail = "{output} has function {output_functions[out_setting[index] & 0x0F]}"
when = "out_setting[index] & 0x0F"

[[procedures.set_output.steps]]
read = ["out_values"]

[[procedures.set_output.steps]]
write.out_values = "out_values | (1 << (index - 1)) if state else out_values & ~(1 << (index - 1))"
"""


def write(tmp_path: Path, text: str, name: str) -> Path:
    p = tmp_path / name
    p.write_text(textwrap.dedent(text), encoding="utf-8")
    return p


def sent(wire: VirtualWire) -> list[str]:
    return [f.data.hex(" ").upper() for f in wire.requests()]


@asynccontextmanager
async def rig(d: Description, **options: object
              ) -> AsyncIterator[tuple[VirtualWire, DescribedProfile]]:
    twin = described_twin(d)(1, FAST)
    async with sim_bus([twin], FAST) as (wire, bus):
        yield wire, profile_class(d)(bus.slave(1), **options)


@pytest.fixture
def base(tmp_path: Path) -> Description:
    return load_description(write(tmp_path, BASE, "base.toml"))


def test_extends_replaces_entries_whole_and_removes_what_the_drive_lacks(
        tmp_path: Path) -> None:
    write(tmp_path, BASE, "base.toml")
    ext = write(tmp_path, """
        extends = "base.toml"

        [drive]
        family = "FEATURES2"

        [remove]
        registers = ["spare"]

        [registers.speed]
        address = 21
        unit = "rpm"
        max = 6000
        """, "ext.toml")
    d = load_description(ext)
    assert d.family == "FEATURES2" and "spare" not in d.regs
    assert (d.regs["speed"].register.address, d.regs["speed"].register.hi) == (21, 6000)
    assert d.regs["points"].register.address == 30  # kept from the base
    bad = write(tmp_path, 'extends = "base.toml"\n[remove]\nregisters = ["nope"]\n', "bad.toml")
    with pytest.raises(ConfigError, match=r"bad\.toml: remove\.registers: base\.toml has no "
                                          r"registers\.nope"):
        load_description(bad)
    loop = write(tmp_path, 'extends = "loop.toml"\n', "loop.toml")
    with pytest.raises(ConfigError, match="extends it in turn"):
        load_description(loop)


def test_extends_takes_a_packaged_description_by_its_family(tmp_path: Path) -> None:
    """The reference's example: a user's file over the packaged NT86, named by its
    family (a file name was taken relative to the user's file, and failed)."""
    ext = write(tmp_path, """
        extends = "NT86"

        [drive]
        family = "NT86-X"
        description = "an NT86 without its position table"

        [remove]
        procedures = ["start_table"]

        [registers.jog_speed]
        address = 77
        name = "jog speed"
        unit = "rpm"
        min = 0
        max = 2000
        default = 500
        """, "nt86x.toml")
    d = load_description(ext)
    assert d.family == "NT86-X" and "start_table" not in d.procedures
    assert d.regs["jog_speed"].register.hi == 2000 and "microstep" in d.regs
    bad = write(tmp_path, 'extends = "NT99"\n', "bad.toml")
    with pytest.raises(ConfigError, match=r"bad\.toml: extends: 'NT99' is no packaged "
                                          r"description \(BHSS, CL86R, EPR60, NT86;"):
        load_description(bad)


def test_list_options_and_option_checks(base: Description) -> None:
    cls = profile_class(base)
    cls.check_options({"outputs": [1, 2]})
    with pytest.raises(ConfigError, match=r"outputs.*less than or equal to 2"):
        cls.check_options({"outputs": [3]})
    with pytest.raises(ConfigError, match="home_input and stop_input are both X2"):
        cls.check_options({"home_input": 2, "stop_input": 2})


async def test_if_changed_writes_only_what_differs(base: Description) -> None:
    async with rig(base, outputs=[1]) as (wire, profile):
        await profile.setup()  # Y1 holds function 3: read, then written to function 0
        assert sent(wire)[:2] == ["01 03 00 0A 00 01 A4 08", "01 06 00 0A 00 00 A9 C8"]
        assert [(r.address, v) for r, v in profile.volatile_settings()] == [(10, 0)]
        wire.clear_log()
        await profile.setup()  # right already: read only
        assert sent(wire) == ["01 03 00 0A 00 01 A4 08"]


async def test_each_writes_a_table_in_one_block(base: Description) -> None:
    async with rig(base) as (wire, profile):
        await profile.fill([5, 6, 7])
        assert sent(wire) == ["01 10 00 1E 00 03 06 00 05 00 06 00 07 EB 23"]
        with pytest.raises(LimitViolation, match=r"point 2 .*0\.\.1000"):
            await profile.fill([1, 1001])
        assert len(sent(wire)) == 1  # checked before the first frame


async def test_the_dry_run_checks_writes_after_a_read(base: Description) -> None:
    async with rig(base) as (wire, profile):
        with pytest.raises(LimitViolation, match="speed"):
            await profile.run_at(4000)
        assert sent(wire) == []


async def test_a_register_read_in_the_procedure_is_written_as_it_is(
        base: Description) -> None:
    """A value that is a register named bare (``copied = "extra"`` after a read of it) is
    the drive's answer: the dry run leaves it to the run (it once range-checked the
    not-yet-read placeholder and refused the procedure: "value <Unread ...> is not a finite
    number")."""
    async with rig(base) as (wire, profile):
        await profile.slave.write_register(40, 7)
        wire.clear_log()
        await profile.copy_points()
        assert sent(wire)[1][:17] == "01 06 00 2A 00 07"  # copied (42) := 7, as read


async def test_outputs_by_name_and_function_names(base: Description) -> None:
    async with rig(base) as (_, profile):
        points = {p.name: p for p in await profile.io_points()}
        assert (points["Y1"].function, points["Y1"].settable) == ("alarm", False)
        assert (points["Y2"].function, points["Y2"].settable) == ("general purpose", True)
        with pytest.raises(NotSupported, match=r"FEATURES.*Y1 has function alarm"):
            await profile.set_output("Y1", True)
        await profile.set_output("Y2", True)
        assert (await profile.slave.read_holding_registers(12, 1)) == [2]
    assert profile_class(base).no_output_control.startswith("an output follows")


async def test_homing_switches_follow_the_options(base: Description) -> None:
    async with rig(base, reverse=True) as (_, profile):
        assert profile.homing_switches(None).reverses_at == {1}
    async with rig(base) as (wire, profile):
        assert profile.homing_switches(None).reverses_at == frozenset()
        with pytest.raises(UnknownMethod, match="no homing method 'index'") as err:
            await profile.home("index")
        assert isinstance(err.value, NotSupported) and isinstance(err.value, ConfigError)
        assert sent(wire) == []
