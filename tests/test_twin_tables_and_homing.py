"""The generic twin's behaviour the NT86's description needs (issue 22): a table of moves
run by the drive itself (``do = "run_table"``), registers set once a motion is over
(``ends``), a write the drive refuses (``do = "refuse"``) and the ``[twin.homing]`` variants
of a reference-edge homing (back-off at the creep speed, stopping at once on the edge, no
reversal or a reversal back onto the same edge, the offset travelled or not). Each on the
twin of a small description, driven register by register at given times; what happened
is read from the twin's registers and its motion trace."""

from __future__ import annotations

import tomllib
from pathlib import Path

import anyio
import pytest

from drivebus import LineSettings
from drivebus.drives.description import load_description, parse_description
from drivebus.drives.engine import profile_class
from drivebus.drives.expr import ExprError
from drivebus.errors import ConfigError
from drivebus.sim import sim_bus
from drivebus.sim.described import DescribedDrive, described_twin
from drivebus.sim.drive import TwinSetup
from drivebus.sim.registers import SlaveException
from test_twin_input_functions import status

TOML = """
[drive]
family = "TBL"

[link]
addresses = "1..31"
baud_rates = [9600, 115200]
formats = ["8N1"]

[link.refusals]
busy = 4

[units.pulses_per_rev]
default = 1000

[registers.status]
address = 0
access = "R"
bits.MOV = { bit = 1, means = "moving" }
bits.HOME = { bit = 2, means = "homed" }

[registers.position]
address = 2
words = 2
signed = true
access = "R"
means = "position"

[registers.command]
address = 4
max = 9

[registers.trigger]
address = 5
max = 9

[registers.rows]
address = 6
min = 1
max = 4
default = 3

[registers.cycle]
address = 7
max = 1

[registers.handling]
address = 8
max = 3

[registers.home_offset]
address = 9
signed = true
unit = "pulses"
min = -1000
max = 1000

[registers.row_target]
address = 20
count = 4
first = 1
stride = 2
words = 2
signed = true
unit = "pulses"

[registers.row_speed]
address = 30
count = 4
first = 1
unit = "rpm"
max = 3000
default = 600

[registers.row_wait]
address = 40
count = 4
first = 1
unit = "ms"
default = 100

[homing.methods.home_positive]
code = 0
behaviour = "reference_edge"
reference = "home_switch"
direction = 1

[twin]
starts = "not moving and not homing"
direct = ["home_switch", "limit_positive", "limit_negative"]
limits = { decel = "1000" }

[twin.homing]
backoff = "creep"
backoff_stop = "at_once"
reverse_at_limit = "handling >= 2"
after_reversal = "same_edge"
offset = "'move' if handling in [1, 3] else 'origin'"

[[twin.on_write]]
register = "command"
when = "value == 1"
do = "run_table"
rows = "rows"
target = "row_target[row]"
speed = "row_speed[row]"
accel = "100"
wait = "row_wait[row] / 1000"
repeat = "cycle == 1"
motion = "table"
refuse = true

[[twin.on_write]]
register = "command"
when = "value == 5"
do = "emergency_stop"
decel = "1000"

[[twin.on_write]]
register = "command"
when = "value == 6"
do = "stop"
decel = "100"

[[twin.on_write]]
register = "trigger"
when = "value == 9"
do = "refuse"

[[twin.on_write]]
register = "trigger"
when = "value == 4"
do = "home"
method = "0"
speed = "600"
creep = "60"
accel = "1000"
offset = "home_offset"
motion = "homing"
refuse = true
ends = { trigger = 0 }
"""

ROOT = Path(__file__).resolve().parents[1]
SPEED = 10_000.0  # 600 rpm at 1000 pulses/rev, pulses/s
CREEP = 1_000.0  # 60 rpm


def twin_class(toml: str = TOML) -> type[DescribedDrive]:
    return described_twin(parse_description(tomllib.loads(toml), "tbl.toml"))


def rests(twin: DescribedDrive, t0: float, t1: float) -> list[tuple[float, float, float]]:
    """(start, duration, position) of each rest between motions in [t0, t1] (the twin
    brought up to ``t1`` first)."""
    twin.advance(t1)
    return [(s.t0, s.duration, s.p0) for s in twin.kin.trace(t0, t1)
            if s.v0 == 0 and s.a == 0 and t0 < s.t0 < t1]


def load_rows(twin: DescribedDrive, targets: list[int], t: float = 0.0) -> None:
    words: list[int] = []
    for target in targets:
        u = target & 0xFFFFFFFF
        words += [u >> 16, u & 0xFFFF]
    twin.write_registers(20, words, t)
    twin.write_register(6, len(targets), t)


# -- run_table ---------------------------------------------------------------------------


def test_a_table_runs_its_rows_with_their_waits_and_moving_throughout() -> None:
    twin = twin_class()(1)
    load_rows(twin, [1000, 3000, 2000])
    twin.write_register(4, 1, 1.0)
    assert status(twin, 1.05) & 0b10
    end = 3.0
    assert twin.position(end) == 2000 and not status(twin, end) & 0b10
    stops = rests(twin, 1.0, end)
    # each row's rest is its wait (100 ms), the last one's is the end: no wait after it
    assert [round(p) for _, _, p in stops] == [1000, 3000, 2000]
    assert [d for _, d, _ in stops[:2]] == [pytest.approx(0.1, abs=1e-9)] * 2
    mid_wait = stops[0][0] + 0.05
    assert status(twin, mid_wait) & 0b10  # moving through the waits (MOV)
    with pytest.raises(SlaveException) as err:
        twin.write_register(4, 1, mid_wait)  # a start while the table runs
    assert err.value.code == 4


def test_a_repeating_table_runs_until_a_stop_and_nothing_of_it_after() -> None:
    twin = twin_class()(1)
    load_rows(twin, [500, 0])
    twin.write_register(7, 1, 0.0)
    twin.write_register(4, 1, 0.0)
    assert [round(p) for _, _, p in rests(twin, 0.0, 1.5)][:4] == [500, 0, 500, 0]
    twin.write_register(4, 6, 1.5)
    assert not twin.is_moving(2.0)
    starts = [s.t0 for s in twin.kin.trace(1.5, 5.0) if s.a > 0 and s.v0 == 0]
    assert starts == []  # no row starts after the stop
    assert not status(twin, 5.0) & 0b10


def test_a_limit_switch_stops_a_table_and_ends_it() -> None:
    twin = twin_class()(1, setup=TwinSetup(limit_positive=2500))
    load_rows(twin, [1000, 3000, 0])
    twin.write_register(4, 1, 0.0)
    assert not twin.is_moving(3.0)
    assert 2500 <= twin.physical_position(3.0) <= 2500 + SPEED**2 / 2e6 + 1
    assert not [s for s in twin.kin.trace(0.0, 5.0) if s.v0 < 0 or (s.a < 0 and s.v0 == 0)]


def test_run_table_needs_its_rows_speed_and_target() -> None:
    bad = TOML.replace('rows = "rows"\n', "")
    with pytest.raises(ConfigError, match=r"on_write\[0\]: run_table needs rows"):
        twin_class(bad)
    bad = TOML.replace('accel = "100"\nwait', 'accel = "100"\nposition = "1"\nwait')
    with pytest.raises(ConfigError, match=r"position: action run_table takes rows"):
        twin_class(bad)


# -- refuse and ends -----------------------------------------------------------------------


def test_a_refused_write_answers_busy_and_keeps_the_register() -> None:
    twin = twin_class()(1)
    twin.write_register(5, 2, 0.0)
    with pytest.raises(SlaveException) as err:
        twin.write_register(5, 9, 0.1)
    assert err.value.code == 4 and twin.read_register(5, 0.1) == 2


def test_a_trigger_register_reads_back_until_its_homing_is_over() -> None:
    twin = twin_class()(1, setup=TwinSetup(home_switch=5000))
    twin.write_register(5, 4, 0.0)
    assert twin.read_register(5, 0.2) == 4 and status(twin, 0.2) & 0b10
    assert not twin.is_moving(3.0)
    assert twin.read_register(5, 3.0) == 0 and status(twin, 3.0) & 0b100  # homed
    twin.write_register(5, 4, 3.1)
    twin.write_register(4, 5, 3.2)  # an e-stop ends it: over, not homed
    assert not twin.is_moving(4.0)
    assert twin.read_register(5, 4.0) == 0 and not status(twin, 4.0) & 0b100


# -- [twin.homing] -------------------------------------------------------------------------


def test_the_back_off_creeps_and_stops_at_once_on_the_edge_it_leaves() -> None:
    twin = twin_class()(1, setup=TwinSetup(home_switch=5000))
    twin.write_register(9, 300, 0.0)  # offset: the origin's coordinate (handling 0)
    twin.write_register(5, 4, 0.0)
    assert not twin.is_moving(3.0) and twin.homed
    assert twin.physical_position(3.0) == 5000 and twin.position(3.0) == 300
    backwards = [abs(s.v0) for s in twin.kin.trace(0.0, 3.0) if s.v0 < 0 and s.a == 0]
    assert backwards and max(backwards) == pytest.approx(CREEP)  # the back-off creeps


def test_a_limit_switch_in_the_search_fails_the_homing_without_reversal() -> None:
    twin = twin_class()(1, setup=TwinSetup(home_switch=-2000, limit_positive=3000),
                        home_switch_width=500)
    twin.write_register(5, 4, 0.0)  # handling 0: no reversal
    assert not twin.is_moving(3.0)
    assert not twin.homed and twin.homing_failed
    assert twin.physical_position(3.0) >= 3000 and twin.read_register(5, 3.0) == 0


def test_a_reversal_passes_back_and_creeps_onto_the_edge_the_search_looked_for() -> None:
    twin = twin_class()(1, setup=TwinSetup(home_switch=-2000, limit_positive=3000),
                        home_switch_width=500)
    twin.write_register(8, 2, 0.0)  # handling 2: reverse at a limit switch
    twin.write_register(5, 4, 0.0)
    assert not twin.is_moving(5.0) and twin.homed
    # searching forwards the origin is the dog's rising edge going forwards, -2000 (not
    # -1500, the edge a search backwards would find)
    assert twin.physical_position(5.0) == -2000 and twin.position(5.0) == 0


def test_the_offset_is_travelled_past_the_origin_when_the_drive_says_so() -> None:
    twin = twin_class()(1, setup=TwinSetup(home_switch=5000))
    twin.write_register(9, 300, 0.0)
    twin.write_register(8, 1, 0.0)  # handling 1: travel the offset, then position = 300
    twin.write_register(5, 4, 0.0)
    assert not twin.is_moving(3.0) and twin.homed
    assert twin.physical_position(3.0) == 5300 and twin.position(3.0) == 300


def test_a_homing_offset_mode_must_be_one_of_three() -> None:
    far = TOML.replace("offset = \"'move' if handling in [1, 3] else 'origin'\"",
                       "offset = \"'far'\"")
    twin = twin_class(far)(1, setup=TwinSetup(home_switch=50))
    with pytest.raises(ExprError, match="'origin', 'move' or 'travel'"):
        twin.write_register(5, 4, 0.0)


def test_a_twin_without_line_settings_takes_the_fastest_rate_in_its_format() -> None:
    assert str(twin_class()(1).settings) == "115200 8N1"


# -- a CiA 402 twin's own flags beside the statusword's state bits --------------------------


async def test_a_cia402_twin_shows_a_homed_flag_the_description_gives_its_statusword() -> None:
    """The Lexium 32's DCOMstatus bit 15 (ref_ok, ``means = "homed"``): clear until a
    homing completes, then set, as the drive's own flag beside the CiA 402 state bits."""
    desc = load_description(ROOT / "configs" / "drives" / "lexium32.toml")
    twin = described_twin(desc)(1)
    async with sim_bus([twin], LineSettings.parse("115200 8N1")) as (_, bus):
        profile = profile_class(desc)(bus.slave(1))
        await profile.setup()
        await profile.enable()
        word = (await bus.slave(1).read_holding_registers(6916, 2))[1]
        assert not word & 0x8000 and not (await profile.read_status()).homed
        await profile.home("position_setting", speed_rpm=60, creep_rpm=10, accel_rps2=10)
        with anyio.fail_after(5):
            while True:  # poll the drive as an axis does, until the homing is over
                if not (await profile.read_status()).homing:
                    break
                await anyio.sleep(0.005)
        word = (await bus.slave(1).read_holding_registers(6916, 2))[1]
        assert word & 0x8000 and twin.homed
