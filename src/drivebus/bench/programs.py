"""Bench rows of the motion scenario for motion programs (issue 24), judged by the twins.

Per drive kind, the dwell between buffered moves (the twin's standstill between one
move's arrival and the next's start, against one poll period); on the CL86R (the drive
that takes a new target on the fly) the lowest speed between blended moves (must stay
above 0); and the path deviation: a buffered XY path on the demo machine (NT86 + BHSS)
and a blended path on two CL86Rs (its twins' own path against the straight segments,
and the prediction the report gives).
"""

from __future__ import annotations

import itertools
import math
import statistics
from typing import Any

import anyio
import anyio.lowlevel

from drivebus.bench.common import BenchResult, at_least, at_most
from drivebus.motion import Machine, MotionHandle, open_machine

__all__ = ["program_rows"]

_BLEND = 1.5
"""The blended path's corner tolerance, mm."""


def _moving_span(twin: Any, t0: float, t1: float) -> list[Any]:
    segs = twin.kin.trace(t0, t1)
    moving = [i for i, s in enumerate(segs) if s.v0 != 0 or s.a != 0]
    return segs[moving[0]: moving[-1] + 1] if moving else []


async def _buffered(m: Machine, name: str, moves: int) -> BenchResult:
    ax, twin = m.axes[name], m.sim_drives[name]
    lo, hi = ax.config.limits or (0.0, 100.0)
    start = lo + 0.2 * (hi - lo)
    await ax.move_to(start)
    step = ax.config.units_per_rev * 0.5
    t0 = anyio.current_time()
    handles: list[MotionHandle] = []
    for i in range(moves):
        h = await ax.move_to(start + step * ((i + 1) % 2), buffer="buffered")
        assert h is not None
        handles.append(h)
    for h in handles:
        await h
    span = _moving_span(twin, t0, anyio.current_time())
    dwells = [s.duration for s in span if s.v0 == 0 and s.a == 0]
    poll = ax.config.poll.moving
    return BenchResult("motion", f"buffered dwell {name} ({ax.profile.family})", {
        "moves": moves,
        "dwell_median_ms": statistics.median(dwells) * 1000,
        "dwell_max_ms": max(dwells) * 1000,
        "poll_ms": poll * 1000,
    }, {"dwell_max_ms": at_most(poll * 1000)})


async def _blended(m: Machine, moves: int) -> BenchResult:
    z, twin = m.axes["z"], m.sim_drives["z"]
    await z.move_to(5.0)
    t0 = anyio.current_time()
    handles: list[MotionHandle] = []
    for i in range(moves):
        speed = 40.0 if i % 2 == 0 else 25.0
        h = await z.move_to(5.0 + 6.0 * (i + 1), speed=speed, buffer="blending")
        assert h is not None
        handles.append(h)
    for h in handles:
        await h
    span = _moving_span(twin, t0, anyio.current_time())[1:-1]  # between start and braking
    low = math.inf
    for s in span:
        end = s.v0 + s.a * s.duration
        low = 0.0 if s.v0 * end <= 0 else min(low, abs(s.v0), abs(end))
    speeds = [h.plan.blend_speed for h in handles[1:] if h.plan.blend_speed is not None]
    return BenchResult("motion", "blend z (CL86R)", {
        "moves": moves,
        "blended": sum(h.plan.runs == "blended" for h in handles),
        "min_speed_between_mm_s": z.units.from_pulses(low) if math.isfinite(low) else 0.0,
        "planned_blend_speed_min": min(speeds, default=0.0),
    }, {"min_speed_between_mm_s": at_least(1.0)})


def _off_path(p: tuple[float, ...], points: list[tuple[float, ...]]) -> float:
    best = math.inf
    for a, b in itertools.pairwise(points):
        ab = [q - r for q, r in zip(b, a, strict=True)]
        length2 = sum(v * v for v in ab) or 1.0
        t = max(0.0, min(1.0, sum((q - r) * d for q, r, d in zip(p, a, ab, strict=True))
                         / length2))
        best = min(best, math.dist(p, [r + t * d for r, d in zip(a, ab, strict=True)]))
    return best


async def _path(m: Machine, names: tuple[str, str], waypoints: list[dict[str, float]],
                blend: float, case: str) -> BenchResult:
    group = m.group(*names)
    start = {n: m.axes[n].position or 0.0 for n in names}
    t0 = anyio.current_time()
    report = await group.path(waypoints, blend=blend)
    t1 = anyio.current_time()
    points = [tuple(start[n] for n in names)]
    for wp in waypoints:
        points.append(tuple(wp.get(n, points[-1][i]) for i, n in enumerate(names)))
    twins = [m.sim_drives[n] for n in names]
    worst = 0.0
    for i in range(801):
        if i % 50 == 0:
            # (the machine goes on polling: 801 samples in one step held its loop 30 ms)
            await anyio.lowlevel.checkpoint()
        t = t0 + (t1 - t0) * i / 800
        p = tuple(m.axes[n].units.from_pulses(tw.kin.position(t))
                  for n, tw in zip(names, twins, strict=True))
        worst = max(worst, _off_path(p, points))
    figures: dict[str, Any] = {
        "segments": len(report.segments),
        "blended_corners": sum(s.ends == "blend" for s in report.segments),
        "deviation_twins_mm": worst,
        "deviation_planned_mm": report.max_deviation,
        "arrival_spread_max_ms": max(s.observed_arrival_spread for s in report.segments)
        * 1000,
    }
    targets = {"deviation_twins_mm": at_most(blend + 0.1)} if blend else {}
    return BenchResult("motion", case, figures, targets)


async def program_rows(m: Machine, quick: bool) -> list[BenchResult]:
    """The rows on the demo machine ``m``, then the blended path on two CL86Rs."""
    moves = 6 if quick else 20
    rows = [await _buffered(m, n, moves) for n in ("x", "y", "z", "r")]
    rows.append(await _blended(m, 5))
    await m.group("x", "y").move_to({"x": 20.0, "y": 10.0})
    rows.append(await _path(m, ("x", "y"), [{"x": 60.0, "y": 30.0}, {"x": 120.0, "y": 40.0},
                                            {"x": 160.0, "y": 90.0}], 0.0,
                            "path buffered x,y (NT86+BHSS)"))
    axes = {
        f"a{i}": {"line": "rs485", "address": i, "drive": "CL86R", "settings": "115200 8N1",
                  "pulses_per_rev": 1000, "units_per_rev": 10.0, "unit": "mm",
                  "speed": 100.0, "accel": 1000.0, "decel": 1000.0,
                  "limits": [-500.0, 500.0], "poll": {"moving": 0.01, "idle": 0.05}}
        for i in (1, 2)}
    cfg = {"name": "bench-blend", "lines": {"rs485": {"port": "sim://bench-blend",
                                                      "settings": "115200 8N1"}},
           "axes": axes}
    async with open_machine(cfg) as cl:
        rows.append(await _path(cl, ("a1", "a2"),
                                [{"a1": 50.0, "a2": 20.0}, {"a1": 100.0, "a2": 30.0},
                                 {"a1": 150.0, "a2": 60.0}, {"a1": 170.0, "a2": 100.0}],
                                _BLEND, f"path blended a1,a2 (CL86R), blend {_BLEND:g} mm"))
    return rows
