"""Bench scenario "motion": the axis's guarantees measured on the demo machine's twins.

Per drive kind: the stop-to-rest time (from ``stop()`` to the twin at rest, and to
``stop()`` returning) against the drive's deceleration time plus two poll periods; the
overshoot of a jog towards a soft limit (must be 0), steady and with a speed change on the
way; and the arrival spread of group moves of mixed distances on RS-485 and TCP (the
twins' own motion ends, against one poll period); the motion programs' rows
(``drivebus.bench.programs``: buffered dwell, blend speed, path deviation). Then the
randomized soak of ``drivebus.sim.soak``: 10 minutes (``--quick``: 20 s, shorter with
shorter runs), its counts and its violations.
"""

from __future__ import annotations

import contextlib
import logging
import statistics
from collections.abc import Iterator
from pathlib import Path

import anyio

from drivebus.bench.common import BenchOptions, BenchResult, Scenario, at_most
from drivebus.bench.programs import program_rows
from drivebus.errors import ConfigError, MotionAborted
from drivebus.machines import DEMO
from drivebus.motion import Axis, AxisState, Machine, open_machine
from drivebus.motion.recording import Recording
from drivebus.sim.soak import run_soak

__all__ = ["SCENARIO"]

log = logging.getLogger(__name__)

_KINDS = ("x", "y", "z", "r")  # NT86, BHSS, CL86R, EPR60 (aux, the OD2000, cannot move)


async def _at_rest(ax: Axis) -> None:
    with anyio.fail_after(30):
        async for st in ax.watch():
            if not st.moving and ax.state in (AxisState.STANDSTILL, AxisState.DISABLED):
                return


async def _stops(m: Machine, name: str, runs: int) -> BenchResult:
    """Stops at full speed in the middle of long moves."""
    ax, twin = m.axes[name], m.sim_drives[name]
    lo, hi = ax.config.limits or (-100.0, 100.0)
    to_rest: list[float] = []
    returned: list[float] = []
    for i in range(runs):
        await _at_rest(ax)
        target = hi - 0.05 * (hi - lo) if i % 2 == 0 else lo + 0.05 * (hi - lo)
        if abs((ax.position or 0.0) - target) < 0.5 * (hi - lo):
            await ax.move_to(lo + 0.5 * (hi - lo))
        async with anyio.create_task_group() as tg:

            async def move(target: float = target) -> None:
                with contextlib.suppress(MotionAborted):  # the stop ends it
                    await ax.move_to(target)

            tg.start_soon(move)
            async for st in ax.watch():
                if st.moving:
                    break
            await anyio.sleep(0.05 + ax.config.speed / ax.config.accel)  # at cruising speed
            t0 = anyio.current_time()
            await ax.stop()
            returned.append(anyio.current_time() - t0)
            to_rest.append(twin.kin.end_time() - t0)
    decel_time = ax.config.speed / ax.config.decel
    target = decel_time + 2 * ax.config.poll.moving
    return BenchResult("motion", f"stop to rest {name} ({ax.profile.family})", {
        "stops": runs,
        "rest_median_ms": statistics.median(to_rest) * 1000,
        "rest_max_ms": max(to_rest) * 1000,
        "return_median_ms": statistics.median(returned) * 1000,
        "return_max_ms": max(returned) * 1000,
    }, {"rest_max_ms": at_most(target * 1000), "return_median_ms": at_most(target * 1000)})


async def _jogs(m: Machine, name: str) -> BenchResult:
    """Jogs at the configured speed towards the upper soft limit, steady and with a change
    of speed on the way: how far past the limit the twin comes to rest."""
    ax, twin = m.axes[name], m.sim_drives[name]
    lo, hi = ax.config.limits or (-100.0, 100.0)
    over: list[float] = []
    for change in (False, True):
        await _at_rest(ax)
        await ax.move_to(hi - 0.25 * (hi - lo))
        await ax.jog(ax.config.speed / 2 if change else ax.config.speed, watchdog=None)
        if change:
            async for st in ax.watch():
                if st.moving:
                    break
            await ax.jog(ax.config.speed, watchdog=None)
        await _at_rest(ax)
        over.append(max(0.0, ax.units.from_pulses(twin.position()) - hi))
    return BenchResult("motion", f"jog overshoot {name} ({ax.profile.family})", {
        "overshoot_steady": over[0], "overshoot_speed_change": over[1],
    }, {"overshoot_steady": at_most(0.0), "overshoot_speed_change": at_most(0.0)})


_MIXES = (
    {"x": 50.0, "y": 30.0, "z": 20.0, "r": 100.0},
    {"x": 52.0, "y": 31.0, "z": 10.0, "r": 110.0},
    {"x": 60.0, "y": 20.0, "z": 12.0, "r": 300.0},
    {"x": 60.2, "y": 20.1, "z": 12.05, "r": 301.0},
    {"x": 10.0, "y": 150.0, "z": 12.0, "r": 300.5},
    {"x": 300.0, "r": 300.8},
)


async def _groups(m: Machine, plots: Path | None) -> BenchResult:
    """Group moves of mixed distances (short, very short, rotary; RS-485 and TCP),
    recorded and drawn into ``plots`` when given."""
    spreads: list[float] = []
    skews: list[float] = []
    async with m.record(axes=_KINDS) as rec:
        for targets in _MIXES:
            before = {n: m.sim_drives[n].position() for n in targets}
            report = await m.group(*targets).move_to(targets)
            moved = [n for n in targets if m.sim_drives[n].position() != before[n]]
            ends = [m.sim_drives[n].kin.end_time() for n in moved]
            spreads.append(max(ends) - min(ends) if ends else 0.0)
            skews.append(report.start_skew)
    if plots is not None:
        _draw(rec, plots)
    return BenchResult("motion", "group arrival (4 drive kinds)", {
        "moves": len(spreads),
        "spread_median_ms": statistics.median(spreads) * 1000,
        "spread_max_ms": max(spreads) * 1000,
        "start_skew_median_ms": statistics.median(skews) * 1000,
    }, {"spread_max_ms": at_most(min(m.axes[n].config.poll.moving for n in _KINDS) * 1000)})


def _draw(rec: Recording, plots: Path) -> None:
    """The group moves' recording as an HTML report (and a PNG with matplotlib)."""
    from drivebus.service.report import report_html, report_png

    plots.mkdir(parents=True, exist_ok=True)
    html = plots / "motion-group-moves.html"
    html.write_text(report_html(rec, title="drivebus bench: group moves of 4 drive kinds"),
                    encoding="utf-8")
    try:
        report_png(rec, plots / "motion-group-moves.png")
    except ConfigError as exc:  # matplotlib is an optional extra
        log.warning("bench: no PNG of the group moves: %s", exc)


@contextlib.contextmanager
def _quiet_axes() -> Iterator[None]:
    """Keep the axes' logs off the bench's output: the soak's injected alarms, power cycles
    and expired watchdogs are logged by the hundred; its report judges them."""
    logger = logging.getLogger("drivebus")
    before = logger.level
    logger.setLevel(logging.CRITICAL)
    try:
        yield
    finally:
        logger.setLevel(before)


async def run(opts: BenchOptions) -> list[BenchResult]:
    """Stops, jogs and group moves per drive kind; then the soak."""
    results: list[BenchResult] = []
    async with open_machine(DEMO) as m:
        for name in _KINDS:
            results.append(await _stops(m, name, 4 if opts.quick else 20))
        for name in _KINDS:
            results.append(await _jogs(m, name))
        results.append(await _groups(m, opts.plots))
        results += await program_rows(m, opts.quick)  # buffered, blended, paths (issue 24)
    seconds = min(20.0, 40 * opts.seconds) if opts.quick else 600.0
    with _quiet_axes():  # the soak's injected alarms and expired watchdogs, logged by the hundred
        report = await run_soak(seconds, seed=20261124, name="bench-soak")
    for text in report.violations:  # (what broke an invariant, in the log beside the row)
        log.error("bench soak: %s", text)
    calls = sum(report.calls.values())
    results.append(BenchResult("motion", f"soak {seconds:.0f} s, 8 axes", {
        "calls": calls,
        "ok": sum(v for k, v in report.outcomes.items() if k.endswith(": ok")),
        "typed_errors": sum(v for k, v in report.outcomes.items()
                            if not k.endswith((": ok", ": cancelled", ": timed out"))),
        "timed_out": sum(v for k, v in report.outcomes.items() if k.endswith(": timed out")),
        "cancelled": sum(v for k, v in report.outcomes.items() if k.endswith(": cancelled")),
        "stops_checked": report.stops_checked,
        "rest_checks": report.rest_checks,
        "power_cycles": report.faults["power cycle"],
        "alarms": report.faults["alarm"],
        "violations": len(report.violations),
    }, {"violations": at_most(0)}))
    return results


SCENARIO = Scenario("motion", 65, run)
