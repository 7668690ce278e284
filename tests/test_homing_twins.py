"""Homing on every family's twin against its manual, direction by direction (issue 21).

Each case drives a profile over a real ``sim://`` line and judges by the twin: where the
motor went first (its physical position sampled at every status poll), the switch edge
it ended on, and what it did at a limit switch. Distances are in motor revolutions
(``R`` pulses), so every family runs the same geometry: limit switches at -2 R and +2 R,
the home switch 1 R from the start. The manuals' method numbers, directions and limit
behaviour are written out here, apart from the profiles and the twins.
"""

from __future__ import annotations

import math
from collections.abc import AsyncIterator, Callable
from contextlib import asynccontextmanager
from dataclasses import dataclass, field
from typing import Any

import anyio
import pytest

from drivebus import LineSettings
from drivebus.clock import monotonic
from drivebus.drives.base import DriveProfile
from drivebus.drives.bhss import BHSSProfile
from drivebus.drives.cl86r import CL86RProfile
from drivebus.drives.nt_family import EPR60Profile, NT86Profile
from drivebus.drives.od_drive import ODDriveProfile
from drivebus.drives.status import DriveStatus
from drivebus.errors import NotSupported
from drivebus.sim import VirtualWire, sim_bus
from drivebus.sim.drive import SimDrive, TwinSetup
from drivebus.sim.drives.bhss import SimBHSS
from drivebus.sim.drives.cl86r import SimCL86R
from drivebus.sim.drives.nt_family import SimEPR60, SimNT86
from drivebus.sim.drives.od_drive import SimODDrive
from nt_helpers import wait_for

FAST = LineSettings.parse("115200 8N1")
LIMIT, HOME, DOG = 2.0, 1.0, 0.25
"""Revolutions: the limit switches at ±LIMIT, the home switch HOME off the start, a dog's
width."""
HOMING = {"speed_rpm": 600.0, "creep_rpm": 240.0, "accel_rps2": 300.0}
"""10 rev/s searching, 4 rev/s creeping, ramps of 300 rev/s² (33 ms: the BHSS's minimum is
30 ms); a stop from the search speed runs 1/6 rev on."""


@dataclass(frozen=True)
class Family:
    """How to rig one family and read back what its twin was told."""

    name: str
    twin: type[SimDrive]
    profile: Callable[..., DriveProfile]
    rev: int
    """Pulses per revolution the profile sets up."""
    methods: dict[str, int]
    """Method name in drivebus -> the manual's method number."""
    method_register: Callable[[Any], int]
    search: Callable[[Any], tuple[float, float]]
    """The twin's search speed (pulses/s) and homing deceleration (pulses/s²)."""
    profile_options: dict[str, Any] = field(default_factory=dict)
    settle: Callable[[Any], float] = lambda sim: 1.0
    """How far from the origin edge the twin may rest (the CL86R brakes from the creep)."""


def _bhss_search(sim: SimBHSS) -> tuple[float, float]:
    speed = min(sim.pulse_rate(sim.regs[0x0032]), 200_000.0)  # 200 kHz pulse output
    return speed, speed / (sim.regs[0x0034] / 1000.0)  # 0x0034: ramp time, ms


def _cl86r_search(sim: SimCL86R) -> tuple[float, float]:
    speed = sim.pulse_rate(sim.regs[0x0041])
    return speed, speed / (sim.regs[0x0043] / 1000.0)  # 0x0043: ramp time, ms


def _cl86r_settle(sim: SimCL86R) -> float:
    """The CL86R ends homing with a decelerating stop from the creep speed (0x0042)."""
    creep, (_, decel) = sim.pulse_rate(sim.regs[0x0042]), _cl86r_search(sim)
    return creep * creep / (2 * decel) + 1


NT86 = Family(
    "NT86", SimNT86, NT86Profile, 4000,
    # Manual 2.6.21, register 288 (and 3.1.2); 5 is printed "positive" (L1158), see the twin.
    {"home_switch_positive": 0, "home_switch_negative": 1, "limit_positive": 2,
     "limit_negative": 3, "hard_stop_positive": 4, "hard_stop_negative": 5},
    lambda sim: sim.params[288],
    lambda sim: (sim.pulse_rate(sim.params[289]), sim.pulse_acceleration(sim.params[291])),
)
EPR60 = Family(
    "EPR60", SimEPR60, EPR60Profile, 4000,
    {"limit_negative": 0, "limit_positive": 1},  # register 79 (L933)
    lambda sim: sim.params[79],
    lambda sim: (sim.pulse_rate(sim.params[80]), sim.pulse_acceleration(sim.params[82])),
    {"home_input": 5},
)
BHSS = Family(
    "BHSS", SimBHSS, BHSSProfile, 1000,
    # Register 0x0031 (L481; 3 is printed "forward" again, §7.9 of the extraction).
    {"forward_limit_origin": 0, "backward_limit_origin": 1, "forward_limit": 2,
     "backward_limit": 3},
    lambda sim: sim.regs[0x0031], _bhss_search,
)
CL86R = Family(
    "CL86R", SimCL86R, CL86RProfile, 1000,
    {"negative_limit": 17, "positive_limit": 18, "home_switch_positive": 24,
     "home_switch_negative": 29},  # register 0x0040 (L253, section 6.3)
    lambda sim: sim.regs[0x0040], _cl86r_search, settle=_cl86r_settle,
)
FAMILIES = {f.name: f for f in (NT86, EPR60, BHSS, CL86R)}

# The manual's search direction and the signal each method homes on.
SEARCH: dict[tuple[str, str], tuple[int, str]] = {
    ("NT86", "home_switch_positive"): (+1, "home"),
    ("NT86", "home_switch_negative"): (-1, "home"),
    ("NT86", "limit_positive"): (+1, "limit"),
    ("NT86", "limit_negative"): (-1, "limit"),
    ("NT86", "hard_stop_positive"): (+1, "hard_stop"),
    ("NT86", "hard_stop_negative"): (-1, "hard_stop"),
    ("EPR60", "limit_negative"): (-1, "limit"),
    ("EPR60", "limit_positive"): (+1, "limit"),
    ("BHSS", "forward_limit_origin"): (+1, "home"),
    ("BHSS", "backward_limit_origin"): (-1, "home"),
    ("BHSS", "forward_limit"): (+1, "limit"),
    ("BHSS", "backward_limit"): (-1, "limit"),
    ("CL86R", "home_switch_positive"): (+1, "home"),
    ("CL86R", "home_switch_negative"): (-1, "home"),
    ("CL86R", "positive_limit"): (+1, "limit"),
    ("CL86R", "negative_limit"): (-1, "limit"),
}
HOME_METHODS = [k for k, (_, signal) in SEARCH.items() if signal == "home"]
LIMIT_METHODS = [k for k, (_, signal) in SEARCH.items() if signal == "limit"]


@dataclass
class Run:
    """One homing: the twin's physical position at the start and at every poll, the last
    status, and the decelerating distance from the search speed."""

    trace: list[float]
    status: DriveStatus
    braking: float
    moves: list[float] = field(default_factory=list)
    """How far from the start the twin's own motion history took it, at each of its
    segments' ends: a busy machine that held the test up for a whole search left the
    polls (``trace``) none of it to see."""

    @property
    def first_direction(self) -> int:
        start = self.trace[0]
        seen = self.moves or [p - start for p in self.trace]
        return next(int(math.copysign(1, d)) for d in seen if abs(d) > 1)

    @property
    def end(self) -> float:
        return self.trace[-1]


@asynccontextmanager
async def rig(
    family: Family, setup: TwinSetup, **twin_options: Any
) -> AsyncIterator[tuple[VirtualWire, Any, DriveProfile]]:
    """``family``'s twin with ``setup`` on a sim line and its set-up profile. Profile
    options ride in ``twin_options`` under the key ``profile``."""
    options = {**family.profile_options, **twin_options.pop("profile", {})}
    sim = family.twin(1, FAST, setup, **twin_options)
    async with sim_bus([sim], FAST) as (wire, bus):
        profile = family.profile(bus.slave(1), **options)
        await profile.setup()
        wire.clear_log()
        yield wire, sim, profile


def revs(family: Family, **positions: float | None) -> TwinSetup:
    """A twin setup with positions given in revolutions."""
    return TwinSetup(**{k: None if v is None else v * family.rev for k, v in positions.items()})


async def home(
    sim: Any, profile: DriveProfile, family: Family, method: str, timeout: float = 10.0,
    **kw: Any,
) -> Run:
    """Home with ``method`` and sample the twin until the drive rests, homing over."""
    began = monotonic()
    trace = [float(sim.physical_position(began))]
    origin = sim.kin.position(began)
    await profile.home(method, **{**HOMING, **kw})
    if method in family.methods:
        assert family.method_register(sim) == family.methods[method]  # the manual's number
    with anyio.fail_after(timeout):
        while True:
            st = await profile.read_status()
            trace.append(float(sim.physical_position()))
            if not st.homing and not st.moving:
                break
            await anyio.sleep(0.002)
    assert not sim.is_moving()
    speed, decel = family.search(sim)
    ended = monotonic()
    moves = [seg.at(min(seg.t1, ended))[0] - origin for seg in sim.kin.trace(began, ended)]
    return Run(trace, st, speed * speed / (2 * decel), moves)


def assert_homed_at(run: Run, sim: Any, family: Family, edge: float) -> None:
    """Homed, at rest on the origin edge ``edge`` (within the family's ``settle``)."""
    assert run.status.homed and not sim.homing_failed
    assert abs(run.end - edge) <= family.settle(sim), (run.end, edge)


def assert_stopped_at_limit(run: Run, sim: Any, limit: float, side: int) -> None:
    """At rest on the limit switch, at most the search's braking distance past it."""
    assert not run.status.homed and not run.status.homing and sim.homing_failed
    assert 0 <= (run.end - limit) * side <= run.braking + 1, (run.end, limit, run.braking)
    assert run.status.limit_positive if side > 0 else run.status.limit_negative


def assert_within_limits(
    run: Run, family: Family, low: float = -LIMIT, high: float = LIMIT
) -> None:
    """Never further past a limit switch than braking from the search speed takes."""
    lo, hi = low * family.rev - run.braking - 1, high * family.rev + run.braking + 1
    assert all(lo <= p <= hi for p in run.trace), (min(run.trace), max(run.trace), lo, hi)


def ids(cases: list[tuple[str, str]]) -> list[str]:
    return [f"{f}-{m}" for f, m in cases]


# -- the profiles' names for the manuals' numbers ---------------------------------------------


def test_profiles_offer_the_manuals_methods() -> None:
    assert set(NT86Profile.homing_methods) == {*NT86.methods, "electrical", "set_origin"}
    assert set(EPR60Profile.homing_methods) == set(EPR60.methods)
    assert set(BHSSProfile.homing_methods) == set(BHSS.methods)
    assert set(CL86RProfile.homing_methods) == {*CL86R.methods, "current_position"}
    assert ODDriveProfile.homing_methods == ()


# -- home switch methods ----------------------------------------------------------------------


@pytest.mark.parametrize(("family", "method"), HOME_METHODS, ids=ids(HOME_METHODS))
async def test_home_switch_ahead_searches_the_manuals_way(family: str, method: str) -> None:
    """① / (a): the switch inactive at the start: search towards it, end on its edge."""
    f = FAMILIES[family]
    d, _ = SEARCH[(family, method)]
    setup = revs(f, home_switch=HOME * d, limit_negative=-LIMIT, limit_positive=LIMIT)
    async with rig(f, setup) as (_, sim, profile):
        run = await home(sim, profile, f, method)
    assert run.first_direction == d
    assert_homed_at(run, sim, f, HOME * d * f.rev)
    assert_within_limits(run, f, -HOME if d < 0 else 0, HOME if d > 0 else 0)


@pytest.mark.parametrize(("family", "method"), HOME_METHODS, ids=ids(HOME_METHODS))
async def test_home_switch_active_at_start_backs_off_first(family: str, method: str) -> None:
    """② / (c): on the switch at the start: creep back to its falling edge, then forward
    to its rising edge (the BHSS manual is silent; its twin does the same)."""
    f = FAMILIES[family]
    d, _ = SEARCH[(family, method)]
    setup = revs(f, position=(HOME + 0.5) * d, home_switch=HOME * d, limit_negative=-LIMIT,
                 limit_positive=LIMIT)
    async with rig(f, setup) as (_, sim, profile):
        run = await home(sim, profile, f, method)
    assert run.first_direction == -d
    assert_homed_at(run, sim, f, HOME * d * f.rev)
    assert_within_limits(run, f)


# Where each family ends when a dog lies behind the start (the search meets the limit
# switch ahead first and reverses), as a function of the search direction d: the dog
# covers [-HOME, -HOME + DOG] for d = +1 and [HOME - DOG, HOME] for d = -1.
DOG_ORIGIN = {
    "NT86": lambda d: -HOME * d,  # ③: back past the dog to its falling edge, creep to rising
    "BHSS": lambda d: -(HOME - DOG) * d,  # the search turns round, homes on the near edge
    "CL86R": lambda d: -HOME * d,  # (b): past the dog, then forward to its rising edge
}


def dog_behind(family: Family, d: int) -> TwinSetup:
    """The dog behind the start, limit switches at ±LIMIT."""
    return revs(family, home_switch=-HOME if d > 0 else HOME - DOG, limit_negative=-LIMIT,
                limit_positive=LIMIT)


@pytest.mark.parametrize(("family", "method"), HOME_METHODS, ids=ids(HOME_METHODS))
async def test_limit_switch_in_the_search_reverses_it(family: str, method: str) -> None:
    """NT86 with 295=2/3 (③), the BHSS (L1184) and the CL86R (24/29 (b)) reverse at the
    limit switch ahead and home on a dog behind the start."""
    f = FAMILIES[family]
    d, _ = SEARCH[(family, method)]
    options: dict[str, Any] = {"home_switch_width": DOG * f.rev}
    if family == "NT86":
        options["profile"] = {"home_reverse_at_limit": True}
    async with rig(f, dog_behind(f, d), **options) as (_, sim, profile):
        run = await home(sim, profile, f, method)
    assert run.first_direction == d
    assert max(p * d for p in run.trace) > (LIMIT - 0.5) * f.rev  # on to the limit switch
    assert_homed_at(run, sim, f, DOG_ORIGIN[family](d) * f.rev)
    assert_within_limits(run, f)


@pytest.mark.parametrize("method", ["home_switch_positive", "home_switch_negative"])
async def test_nt86_stops_at_the_limit_switch_with_295_0(method: str) -> None:
    """③ with 295=0/1: "stop and wait for the host to trigger homing again"."""
    d, _ = SEARCH[("NT86", method)]
    setup = dog_behind(NT86, d)
    async with rig(NT86, setup, home_switch_width=DOG * NT86.rev) as (_, sim, profile):
        run = await home(sim, profile, NT86, method)
        assert sim.params[287] == 0  # a new trigger is needed
    assert run.first_direction == d
    assert_stopped_at_limit(run, sim, LIMIT * d * NT86.rev, d)


# What the twin does with no home switch at all: where it ends (the limit switch it stops
# at: +1 the one in the search direction, -1 the other) and whether it reversed first.
MISSING_SWITCH = {
    ("NT86", False): 1,  # 295=0/1: stops at the first limit switch
    ("NT86", True): -1,  # 295=2/3: reverses there, stops at the other (manual silent)
    ("BHSS", False): -1,  # reverses at the first (L1184), stops at the other (silent)
    ("CL86R", False): -1,  # (b) reverses at the first, stops at the other (silent)
}


MISSING_CASES = [(f, m, r) for f, m in HOME_METHODS for r in (False, True)
                 if (f, r) in MISSING_SWITCH]


@pytest.mark.parametrize(("family", "method", "reverse"), MISSING_CASES,
                         ids=[f"{f}-{m}" + ("-295=2" if r else "-295=0" if f == "NT86" else "")
                              for f, m, r in MISSING_CASES])
async def test_missing_home_switch_ends_at_a_limit_switch(
    family: str, method: str, reverse: bool
) -> None:
    f = FAMILIES[family]
    d, _ = SEARCH[(family, method)]
    options = {"profile": {"home_reverse_at_limit": reverse}} if family == "NT86" else {}
    setup = revs(f, limit_negative=-LIMIT, limit_positive=LIMIT)
    async with rig(f, setup, **options) as (
        _, sim, profile
    ):
        run = await home(sim, profile, f, method)
    side = MISSING_SWITCH[(family, reverse)] * d
    assert run.first_direction == d
    assert_stopped_at_limit(run, sim, LIMIT * side * f.rev, side)
    assert_within_limits(run, f)


@pytest.mark.parametrize(("family", "method"), HOME_METHODS, ids=ids(HOME_METHODS))
async def test_starting_on_the_limit_switch_ahead(family: str, method: str) -> None:
    """On the limit switch in the search direction at the start, no home switch: the NT86
    (295=0) stops at once, the BHSS and the CL86R reverse at once; none goes further out."""
    f = FAMILIES[family]
    d, _ = SEARCH[(family, method)]
    setup = revs(f, position=(LIMIT + 0.05) * d, limit_negative=-LIMIT, limit_positive=LIMIT)
    async with rig(f, setup) as (_, sim, profile):
        run = await home(sim, profile, f, method)
    assert all((p - run.trace[0]) * d <= 1 for p in run.trace)  # never further out
    if family == "NT86":
        assert run.end == run.trace[0] and not run.status.homed and sim.homing_failed
        assert run.status.limit_positive if d > 0 else run.status.limit_negative
    else:
        assert run.first_direction == -d
        assert_stopped_at_limit(run, sim, -LIMIT * d * f.rev, -d)


async def test_issue_21_home_switch_negative_goes_negative_and_never_runs_through() -> None:
    """The reported case in pulses (0.05 mm/pulse): from 295 mm, home switch at 1 mm, the
    positive limit switch at 305 mm. 288=1 searches negative and homes at 1 mm."""
    setup = TwinSetup(position=5900, home_switch=20, limit_positive=6100)
    async with rig(NT86, setup) as (_, sim, profile):
        run = await home(sim, profile, NT86, "home_switch_negative")
    assert run.first_direction == -1
    assert_homed_at(run, sim, NT86, 20)
    # A cam that covers the positive side instead is active at 295 mm: 288=1 backs off
    # positive (②) and meets the limit switch, where the twin stops (the manual is silent).
    async with rig(NT86, setup, home_cam="positive") as (_, sim, profile):
        run = await home(sim, profile, NT86, "home_switch_negative")
    assert run.first_direction == 1
    assert not run.status.homed and sim.homing_failed and run.status.limit_positive
    creep = sim.pulse_rate(sim.params[290]) ** 2 / (2 * sim.pulse_acceleration(sim.params[291]))
    assert 6100 <= run.end <= 6100 + creep + 1


# -- limit switch methods ---------------------------------------------------------------------


@pytest.mark.parametrize(("family", "method"), LIMIT_METHODS, ids=ids(LIMIT_METHODS))
@pytest.mark.parametrize("start", [0.0, LIMIT + 0.1], ids=["off", "on"])
async def test_limit_methods_home_on_their_limit_switch(
    family: str, method: str, start: float
) -> None:
    f = FAMILIES[family]
    d, _ = SEARCH[(family, method)]
    setup = revs(f, position=start * d, limit_negative=-LIMIT, limit_positive=LIMIT)
    async with rig(f, setup) as (_, sim, profile):
        run = await home(sim, profile, f, method)
    assert run.first_direction == (d if start == 0 else -d)
    # Every family's limit methods end on the switch's inner edge (EPR60: with 83 = 0).
    assert_homed_at(run, sim, f, LIMIT * d * f.rev)
    # On that edge the switch still reads active where the origin is its rising edge
    # (NT86 2/3, BHSS 2/3, EPR60 with 83 = 0); the CL86R's is the falling edge (17/18).
    on_limit = run.status.limit_positive if d > 0 else run.status.limit_negative
    assert on_limit == (family != "CL86R")
    assert_within_limits(run, f)


@pytest.mark.parametrize(("family", "method"), LIMIT_METHODS, ids=ids(LIMIT_METHODS))
async def test_limit_methods_without_their_switch_run_until_stopped(
    family: str, method: str
) -> None:
    """No limit switch where the method homes: the drive cannot know; every manual has it
    search on (the axis layer's watchdog must stop it). Stopping it ends homing."""
    f = FAMILIES[family]
    d, _ = SEARCH[(family, method)]
    setup = revs(f, **{"limit_negative" if d > 0 else "limit_positive": -LIMIT * d})
    async with rig(f, setup) as (_, sim, profile):
        await profile.home(method, **HOMING)
        with anyio.fail_after(10):
            while sim.physical_position() * d < (LIMIT + 1.5) * f.rev:
                assert (await profile.read_status()).homing
                await anyio.sleep(0.005)
        await profile.stop()
        st = await wait_for(profile, lambda s: not s.moving and not s.homing)
    assert not st.homed and not sim.homing_failed


# -- NT86 hard stop and electrical homing, OD2000 ---------------------------------------------


@pytest.mark.parametrize("method", ["hard_stop_positive", "hard_stop_negative"])
@pytest.mark.parametrize("stop", [HOME, None], ids=["stop", "no_stop"])
async def test_nt86_hard_stop_homing(method: str, stop: float | None) -> None:
    """288=4/5 creep into the end stop; with none before the limit switch, the twin stops
    at the limit switch (the manual is silent)."""
    d, _ = SEARCH[("NT86", method)]
    ends = {"hard_stop_positive" if d > 0 else "hard_stop_negative":
            None if stop is None else stop * d * NT86.rev}
    setup = revs(NT86, limit_negative=-LIMIT, limit_positive=LIMIT)
    async with rig(NT86, setup, control_mode=1, **ends) as (_, sim, profile):
        await profile.slave.write_register(296, 1000)  # 50 ms stall time
        run = await home(sim, profile, NT86, method)
    assert run.first_direction == d
    if stop is None:
        creep = sim.pulse_rate(sim.params[290]) ** 2 / (2 * sim.pulse_acceleration(sim.params[291]))
        assert not run.status.homed and sim.homing_failed
        assert 0 <= run.end * d - LIMIT * NT86.rev <= creep + 1
    else:
        assert_homed_at(run, sim, NT86, stop * d * NT86.rev)


@pytest.mark.parametrize("target", [HOME, LIMIT + 1, -LIMIT - 1])
async def test_nt86_electrical_homing_stops_at_a_limit_switch(target: float) -> None:
    """287=5 moves to 293/294; a limit switch on the way stops it (the manual is silent)."""
    setup = revs(NT86, limit_negative=-LIMIT, limit_positive=LIMIT)
    async with rig(NT86, setup) as (_, sim, profile):
        run = await home(sim, profile, NT86, "electrical", offset=round(target * NT86.rev))
    d = 1 if target > 0 else -1
    assert run.first_direction == d
    if abs(target) < LIMIT:
        assert_homed_at(run, sim, NT86, target * NT86.rev)
    else:
        assert_stopped_at_limit(run, sim, LIMIT * d * NT86.rev, d)


async def test_nt86_set_origin_does_not_move() -> None:
    async with rig(NT86, revs(NT86, position=1.0)) as (_, sim, profile):
        run = await home(sim, profile, NT86, "set_origin", offset=77)
    assert run.status.homed and run.status.position == 77 and set(run.trace) == {4000.0}


async def test_od2000_cannot_home_and_writes_nothing() -> None:
    """The OD2000's serial port has no homing objects: home() is NotSupported, no frame."""
    sim = SimODDrive(setup=TwinSetup(home_switch=500, limit_negative=-1000))
    async with sim_bus([sim], LineSettings.parse("9600 8N1")) as (wire, bus):
        profile = ODDriveProfile(bus.slave(1))
        with pytest.raises(NotSupported, match="home"):
            await profile.home()
        assert wire.requests() == []
