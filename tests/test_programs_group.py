"""Group moves with a speed, ramps or a duration, group paths and queued group moves,
judged by the twins' motion history and the wire log."""

from __future__ import annotations

import itertools
import math
from pathlib import Path
from typing import Any

import anyio
import anyio.lowlevel
import pytest

from drivebus import open_machine
from drivebus.errors import (
    ArgumentError,
    GroupMotionError,
    LimitViolation,
    MotionAborted,
    StateError,
)
from drivebus.motion import Machine
from drivebus.motion.path import GroupHandle
from held_up import within_bound
from test_axis_guarantees import commands, log_size
from test_motion import machine
from wirelog import reads_of

DEMO = Path(__file__).resolve().parents[1] / "configs" / "demo.toml"


def moves(twin: Any, t0: float, t1: float) -> list[tuple[float, float]]:
    """The twin's motions between ``t0`` and ``t1``: (start, end) of each run of motion."""
    out: list[tuple[float, float]] = []
    for s in twin.kin.trace(t0, t1):
        if s.v0 == 0 and s.a == 0:
            continue
        if out and abs(out[-1][1] - s.t0) < 1e-9:
            out[-1] = (out[-1][0], s.t1)
        else:
            out.append((s.t0, s.t1))
    return out


def twin_point(m: Machine, names: list[str], t: float) -> dict[str, float]:
    """Where the twins of ``names`` are at ``t``, in the axes' units."""
    return {n: m.axes[n].units.from_pulses(m.sim_drives[n].kin.position(t)) for n in names}


def off_polyline(p: dict[str, float], points: list[dict[str, float]]) -> float:
    best = math.inf
    for a, b in itertools.pairwise(points):
        ab = {n: b[n] - a[n] for n in a}
        length2 = sum(v * v for v in ab.values()) or 1.0
        s = max(0.0, min(1.0, sum((p[n] - a[n]) * ab[n] for n in a) / length2))
        best = min(best, math.dist([p[n] for n in a], [a[n] + s * ab[n] for n in a]))
    return best


async def test_a_group_move_takes_a_path_speed_ramps_or_a_duration() -> None:
    async with open_machine(DEMO) as m:
        xy = m.group("x", "y")
        await xy.move_to({"x": 20.0, "y": 10.0})
        report = await xy.move_to({"x": 50.0, "y": 50.0}, speed=40.0, accel=400.0)
        # the straight line is 50 mm long: x covers 30 of it (3/5), y 40 (4/5)
        assert report.plans["x"].speed == pytest.approx(24.0, rel=0.03)
        assert report.plans["y"].speed == pytest.approx(32.0, rel=0.03)
        assert m.axes["x"].position == 50.0 and m.axes["y"].position == 50.0
        report = await xy.move_to({"x": 20.0, "y": 10.0}, duration=2.5)
        assert report.duration == pytest.approx(2.5, abs=0.01)
        assert m.sim_drives["x"].position() == m.axes["x"].units.to_pulses(20.0)
        with pytest.raises(LimitViolation, match=r"axis y needs at least"):
            await xy.move_to({"x": 20.0, "y": 190.0}, duration=0.5)
        with pytest.raises(ArgumentError, match="one unit"):
            await m.group("x", "r").move_to({"x": 30.0, "r": 90.0}, speed=10.0)
        with pytest.raises(ArgumentError, match="not both"):
            await xy.move_to({"x": 30.0, "y": 30.0}, speed=10.0, duration=3.0)
        assert m.axes["x"].position == 20.0 and m.axes["y"].position == 10.0  # nothing moved


async def test_a_path_speed_takes_an_axis_that_moves_too_little_for_its_drives_ramps(
) -> None:
    """x moves 2 mm of a 143 mm line: its share of the path's ramps is below the least
    its NT86 runs. Without a speed the fit takes its ramps up to the drive's; with one,
    the move and the path were refused (``accel 8.39 mm/s² is below the 95 mm/s² its
    drive runs at least``), though slower than the axes' defaults."""
    async with open_machine(DEMO) as m:
        xy = m.group("x", "y")
        speed = 50.0  # y's own is 60 mm/s

        async def group_move(attempt: int) -> float:
            await xy.move_to({"x": 12.0, "y": 7.0})
            report = await xy.move_to({"x": 14.0, "y": 150.0}, speed=speed)
            assert report.plans["y"].speed <= speed * 1.02  # the path's speed holds
            # arrival is the twins' own: the end of their planned motion
            ends = [m.sim_drives[n].kin.end_time() for n in ("x", "y")]
            return max(ends) - min(ends) - min(m.axes[n].config.poll.moving for n in "xy")

        await within_bound(group_move, "x and y arriving within a poll period")
        await xy.path([{"x": 12.0, "y": 7.0}], speed=speed)
        for n, target in (("x", 12.0), ("y", 7.0)):
            assert m.sim_drives[n].position() == m.axes[n].units.to_pulses(target)


async def test_a_path_planned_while_one_of_its_axes_starts_another_move_is_refused(
) -> None:
    """Planning a long path takes a while; an axis of it that another task moves meanwhile
    is no longer where the plan starts. The path used to run its first segment from the
    stale start and fail on its deadline; it is refused, nothing of it
    started."""
    async with open_machine(DEMO) as m:
        xy = m.group("x", "y")
        await xy.move_to({"x": 12.0, "y": 7.0})
        corners = [{"x": 100.0 + 2.0 * (i % 2), "y": 50.0 + i} for i in range(100)]
        y_at = m.sim_drives["y"].position()
        outcome: list[BaseException] = []

        async def path() -> None:
            try:
                await xy.path(corners)
            except StateError as exc:
                outcome.append(exc)

        with anyio.fail_after(120):
            async with anyio.create_task_group() as tg:
                tg.start_soon(path)
                await anyio.lowlevel.checkpoint()  # the path has its axes' places
                await m.axes["x"].move_to(20.0)  # done while the path is planned
        assert [str(e) for e in outcome] == ["the path was refused: axis x started another "
                                             "motion while it was being planned, from where "
                                             "it no longer is"]
        assert m.sim_drives["y"].position() == y_at  # nothing of the path started


async def test_a_buffered_path_stops_in_position_at_each_corner_within_a_poll_period() -> None:
    """Each corner's next segment starts on the first status that can show the axes of the
    segment before it arrived: no more than one status read of an arrived axis begins
    between its arrival and the next start (a poll period at most, whatever the machine's
    load does to the period itself; the dwell is the bench's figure)."""
    async with open_machine(DEMO) as m:
        xy = m.group("x", "y")
        corners = [{"x": 60.0}, {"y": 40.0}, {"x": 20.0, "y": 20.0}, {"y": 10.0}]

        async def path(attempt: int) -> float:
            await xy.move_to({"x": 20.0, "y": 10.0})
            t0 = anyio.current_time()
            report = await xy.path(corners, speed=50.0)
            t1 = anyio.current_time()
            assert [s.ends for s in report.segments] == ["stop", "stop", "stop", "end"]
            assert all("blend is 0" in s.reason for s in report.segments[:-1])
            assert m.sim_drives["x"].position() == m.axes["x"].units.to_pulses(20.0)
            assert m.sim_drives["y"].position() == m.axes["y"].units.to_pulses(10.0)
            xs, ys = moves(m.sim_drives["x"], t0, t1), moves(m.sim_drives["y"], t0, t1)
            assert len(xs) == 2 and len(ys) == 3  # x: segments 1, 3; y: 2, 3, 4
            deviation = report.segments[2].max_deviation  # the diagonal: < 0.5 mm
            segment_moves = [[("x", *xs[0])], [("y", *ys[0])],
                             [("x", *xs[1]), ("y", *ys[1])], [("y", *ys[2])]]
            reads = {n: reads_of(m, n) for n in ("x", "y")}
            # (its axes' start skew: a distance converts at the path's speed)
            late = [-1.0 if deviation < 0.5 else max((deviation - 0.5) / 50.0, 1e-9)]
            for before, after in itertools.pairwise(segment_moves):
                arrived = max(end for _, _, end in before)
                started = min(start for _, start, _ in after)
                assert started >= arrived, (before, after)
                # a second read of an arrived axis before the next start: the start came
                # that much too late (a held-up process: the twins run in it)
                for n, _, end in before:
                    inside = sorted(t for t in reads[n] if end < t < started)
                    if len(inside) > 1:
                        late.append(started - inside[1])
            return max(late)

        await within_bound(path, "each corner's start before a second poll of an arrived axis, "
                                 "and the diagonal within 0.5 mm")


@pytest.mark.serial  # each blend must reach the drives before they stop: a deadline that CPU
# load from other tests moves
async def test_a_blended_path_never_stops_and_stays_within_its_blend_distance() -> None:
    async with open_machine(machine(2, "CL86R")) as m:
        g = m.group("a1", "a2")
        start = {"a1": 0.0, "a2": 0.0}
        waypoints = [{"a1": 50.0, "a2": 20.0}, {"a1": 100.0, "a2": 30.0},
                     {"a1": 150.0, "a2": 60.0}, {"a1": 170.0, "a2": 100.0}]
        speed = max(m.axes[n].config.speed for n in start)

        async def path(attempt: int) -> float:
            # A blend that reaches the drives late (a held-up process: the twins run in it)
            # lets them run on straight (off the path by as much as they went meanwhile)
            # or stop (for as long as it was late). Judged as that lateness, in seconds.
            if attempt > 1:
                await g.move_to(start)
            t0 = anyio.current_time()
            report = await g.path(waypoints, blend=1.5)
            t1 = anyio.current_time()
            assert [s.ends for s in report.segments] == ["blend", "blend", "blend", "end"]
            runs = {n: moves(m.sim_drives[n], t0, t1) for n in start}
            for n in start:
                assert runs[n], n
                assert m.sim_drives[n].position() == m.axes[n].units.to_pulses(
                    waypoints[-1][n])
            pauses = [nxt[0] - run[1] for n in start
                      for run, nxt in itertools.pairwise(runs[n])]
            if pauses:  # it stopped on the way: no run from start to finish
                return max(pauses) + 1e-6
            begin, end = runs["a1"][0]
            points = [start, *waypoints]
            worst = max(off_polyline(twin_point(m, ["a1", "a2"], begin + (end - begin) * i / 400),
                                     points) for i in range(401))
            # the report's deviation, and the twins' own path (not the prediction)
            return max(report.max_deviation - (1.5 + 0.05), worst - (1.5 + 0.1)) / speed

        await within_bound(path, "a blended path within its blend distance, without a stop")


async def test_a_path_on_drives_that_cannot_blend_buffers_and_says_why() -> None:
    async with open_machine(DEMO) as m:
        xy = m.group("x", "y")
        await xy.move_to({"x": 20.0, "y": 10.0})
        report = await xy.path([{"x": 40.0, "y": 20.0}, {"x": 60.0, "y": 40.0}], blend=2.0)
        assert report.segments[0].ends == "stop"
        assert "NT86" in report.segments[0].reason and "manual" in report.segments[0].reason


async def test_a_stop_during_a_path_leaves_every_drive_at_rest_and_drops_the_rest() -> None:
    async with open_machine(DEMO) as m:
        xy = m.group("x", "y")
        await xy.move_to({"x": 20.0, "y": 10.0})
        for delay in (0.0, 0.05, 0.4, 0.9):
            await xy.move_to({"x": 20.0, "y": 10.0})
            marks = {n: log_size(m, n) for n in ("x", "y")}
            outcome: list[BaseException] = []

            async def run(out: list[BaseException] = outcome) -> None:
                try:
                    await xy.path([{"x": 60.0}, {"y": 40.0}, {"x": 20.0}, {"y": 10.0}])
                except GroupMotionError as exc:
                    out.append(exc)

            async with anyio.create_task_group() as tg:
                tg.start_soon(run)
                async for _ in m.axes["x"].watch():  # the path has begun
                    if m.axes["x"].busy:
                        break
                await anyio.sleep(delay)
                await m.axes["y"].stop()
            assert outcome and isinstance(outcome[0].__cause__, MotionAborted), delay
            for n in ("x", "y"):
                assert not m.sim_drives[n].is_moving()
                assert m.axes[n].queued == 0
                cmds = commands(m, n, marks[n])
                if "stop" in cmds:
                    assert "start" not in cmds[cmds.index("stop"):], (n, delay, cmds)


async def test_a_cancelled_path_stops_every_axis() -> None:
    async with open_machine(DEMO) as m:
        xy = m.group("x", "y")
        await xy.move_to({"x": 20.0, "y": 10.0})
        with anyio.move_on_after(0.5):
            await xy.path([{"x": 200.0}, {"y": 150.0}])
        assert not m.sim_drives["x"].is_moving() and not m.sim_drives["y"].is_moving()
        assert m.axes["x"].queued == 0 and m.axes["y"].queued == 0


async def test_a_queued_group_move_starts_when_every_axis_of_it_is_done() -> None:
    async with open_machine(DEMO) as m:
        xy = m.group("x", "y")
        x, y = m.axes["x"], m.axes["y"]
        await xy.move_to({"x": 20.0, "y": 10.0})
        t0 = anyio.current_time()
        first = await x.move_to(80.0, buffer="buffered")  # x alone, a long way
        queued = await xy.move_to({"x": 40.0, "y": 30.0}, buffer="buffered")
        assert isinstance(queued, GroupHandle)
        await first
        report = await queued
        t1 = anyio.current_time()
        xs, ys = moves(m.sim_drives["x"], t0, t1), moves(m.sim_drives["y"], t0, t1)
        assert len(xs) == 2 and len(ys) == 1
        assert ys[0][0] >= xs[0][1]  # y waited for x's first move
        assert x.position == 40.0 and y.position == 30.0
        assert report.segments[0].end == {"x": 40.0, "y": 30.0}
