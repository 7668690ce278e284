"""What writing a drive from its manual as a newcomer found (the Arcus TITAN-SVX,
tests/drives/arcus_titan_svx.toml): each on the generic twin of a small description, on
the wire.

* ``DriveStatus.raw`` keeps each polled register's own value: a register with a unit gave
  its physical value (a count scaled by 2 read twice its word) or, where that was not a
  whole number (a speed in 0.1 rpm), was left out.
* A command coil the drive does not read back (``coil = true, access = "W"``: the TITAN
  serves FC01 on coils 0..6 only) is refused to FC01 by the twin, as a write-only register
  is to FC03; the twin answered it.
* A drive without a homed flag, homed by a method that sets the position at once
  (``behaviour = "set"``: the TITAN writes its encoder position EX), reports homed once
  that homing is done; ``axis.home()`` waited for a flag the drive does not have.
"""

from __future__ import annotations

import textwrap
from collections.abc import AsyncIterator
from contextlib import asynccontextmanager
from pathlib import Path

import pytest

from drivebus import LineSettings
from drivebus.drives.base import HomingParams
from drivebus.drives.description import Description, load_description
from drivebus.drives.engine import DescribedProfile, profile_class
from drivebus.errors import ConfigError, ModbusException
from drivebus.sim import VirtualWire, sim_bus
from drivebus.sim.described import described_twin

FAST = LineSettings.parse("115200 8N1")

DRIVE = """
[drive]
family = "NEWCOMER"
source = "inferred: a test's drive"

[link]
functions = [1, 3, 5, 16]

[units.pulses_per_rev]
default = 1000

[registers.status]
address = 0
access = "R"
bits.ENABLED = { bit = 0, means = "enabled" }
bits.MOVING = { bit = 1, means = "moving" }

[registers.position]
address = 2
words = 2
signed = true
unit = "pulses"
means = "position"

[registers.speed]
address = 4
signed = true
unit = "rpm"
scale = 0.1
access = "R"
means = "velocity"

[registers.steps]
address = 5
unit = "steps/rev"
scale = 2
default = 5000

[registers.servo_on]
address = 104
coil = true
access = "W"

[status]
poll = ["status", "position", "speed", "steps"]

[homing.methods]
set_here = { code = 0, behaviour = "set" }

[procedures.enable]
steps = [{ write = { servo_on = 1 } }]

[procedures.home]
steps = [{ write = { position = "offset" } }]

[twin]
on_write = [
  { register = "servo_on", when = "value == 1", do = "enable" },
  { register = "position", when = "not moving", do = "home", method = 0, offset = "value" },
]
"""


@asynccontextmanager
async def rig(tmp_path: Path) -> AsyncIterator[tuple[VirtualWire, DescribedProfile, object]]:
    path = tmp_path / "newcomer.toml"
    path.write_text(textwrap.dedent(DRIVE), encoding="utf-8")
    d: Description = load_description(path)
    twin = described_twin(d)(1, FAST)
    async with sim_bus([twin], FAST) as (wire, bus):
        yield wire, profile_class(d)(bus.slave(1)), twin


async def test_status_raw_keeps_each_polled_registers_own_value(tmp_path: Path) -> None:
    async with rig(tmp_path) as (_, profile, _twin):
        st = await profile.read_status()
        assert st.velocity_rpm == 0.0
        assert st.raw["speed"] == 0  # a physical 0.0 rpm: it was left out
        assert st.raw["steps"] == 5000  # the word, not the 10 000 steps/rev it stands for
        assert st.raw["position"] == 0


async def test_a_write_only_coil_is_not_read_back_by_the_twin(tmp_path: Path) -> None:
    async with rig(tmp_path) as (_, profile, twin):
        await profile.enable()
        assert twin.enabled  # type: ignore[attr-defined]
        with pytest.raises(ModbusException) as refused:
            await profile.slave.read_coils(104, 1)
        assert refused.value.function == 0x01


async def test_a_set_homing_without_a_homed_flag_reports_homed(tmp_path: Path) -> None:
    async with rig(tmp_path) as (_, profile, twin):
        await profile.setup()
        await profile.enable()
        assert not (await profile.read_status()).homed
        await profile.start_homing(HomingParams(offset=-250))
        st = await profile.read_status()
        assert st.homed and st.position == -250 and twin.position() == -250  # type: ignore[attr-defined]
        await profile.setup()  # set up again (after a power loss): no longer homed
        assert not (await profile.read_status()).homed


def test_the_drive_page_shows_the_status_decoded_from_the_meanings(tmp_path: Path) -> None:
    """``drivebus drive doc`` showed '-' for every status field a description decodes from
    its registers' and bits' meanings (as most do), though ``drive check`` shows them."""
    from drivebus.app.drives import doc_page, load

    path = tmp_path / "newcomer.toml"
    path.write_text(textwrap.dedent(DRIVE), encoding="utf-8")
    page = doc_page(load(path))
    assert "| moving | `status.MOVING` (from the meanings) |" in page
    assert "| position | `position` (from the meanings) |" in page
    assert "| homed | - |" in page


def test_the_drive_page_says_a_save_is_refused_where_the_drive_has_none(
        tmp_path: Path) -> None:
    """The page said '`--save` makes the drive store them once at the end (its save
    command)' for a drive without one, where ``params load --save`` is refused."""
    from drivebus.app.drives import doc_page, load

    path = tmp_path / "newcomer.toml"
    path.write_text(textwrap.dedent(DRIVE), encoding="utf-8")
    page = doc_page(load(path))
    assert "its save command" not in page
    assert ("`--save` is refused: the NEWCOMER drive cannot save parameters over Modbus: "
            "its description has no [procedures.save_parameters]") in page


def test_check_warns_where_home_cannot_complete(tmp_path: Path) -> None:
    """A homing method that runs on the drive (not ``behaviour = "set"``) and no homed
    decoding: ``home()`` waits for a flag the drive does not show. ``drive check`` said
    nothing of it; ``drive try`` failed after 30 s."""
    from drivebus.app.drives import check_report, load

    path = tmp_path / "newcomer.toml"
    path.write_text(textwrap.dedent(DRIVE), encoding="utf-8")
    assert not [w for w in check_report(load(path)).warnings if "homed" in w]
    path.write_text(textwrap.dedent(DRIVE).replace(
        'set_here = { code = 0, behaviour = "set" }', "switch = { code = 1, cia402 = 19 }"),
        encoding="utf-8")
    assert [w for w in check_report(load(path)).warnings
            if w.startswith("status.homed is not decoded: home() with switch waits")]


def test_check_warns_of_a_homing_method_key_that_looks_misspelt(tmp_path: Path) -> None:
    """A homing method's further values are the drive's own (``home.NAME``), so ``cod``
    for ``code`` was taken silently and ``drive try`` failed with "home.code is not
    given"; ``drive check`` now asks."""
    from drivebus.app.drives import check_report, load

    path = tmp_path / "newcomer.toml"
    path.write_text(textwrap.dedent(DRIVE).replace(
        'set_here = { code = 0, behaviour = "set" }',
        'set_here = { cod = 0, behaviour = "set", speed_table = 3 }'), encoding="utf-8")
    warnings = check_report(load(path)).warnings
    assert "homing.methods.set_here.cod: did you mean 'code'? (taken as a value of the " \
        "drive's own, home.cod)" in warnings, warnings
    assert not [w for w in warnings if "speed_table" in w]  # a value of its own: no question


def test_a_manuals_whole_list_of_function_codes_is_taken_less_those_never_sent(
        tmp_path: Path) -> None:
    """The TITAN's manual lists FC08 (diagnostics) among its function codes; copied into
    ``[link] functions`` it was refused as 'Input should be 1, 2, 3, 4, 5, 6 or 16'. The
    list is true of the drive: the codes drivebus never sends are left out. What is no
    function code at all is still refused, naming it."""
    path = tmp_path / "newcomer.toml"
    path.write_text(textwrap.dedent(DRIVE).replace("functions = [1, 3, 5, 16]",
                                                   "functions = [1, 3, 5, 8, 15, 16, 23]"),
                    encoding="utf-8")
    assert load_description(path).link.functions == [1, 3, 5, 16]
    path.write_text(textwrap.dedent(DRIVE).replace("functions = [1, 3, 5, 16]",
                                                   "functions = [1, 3, 131, 16]"),
                    encoding="utf-8")
    with pytest.raises(ConfigError, match=r"link\.functions: 131: not a Modbus function "
                       r"code \(1\.\.127\)"):
        load_description(path)
