"""Group paths: synchronised straight segments through waypoints, buffered or blended.

``AxisGroup.path`` plans every segment first (each a synchronised move, fitted to the
drives; a refusal sends nothing), then queues each axis's part of every segment on that
axis: the first segment starts through the group's start gate (lines held, starts back to
back), each later one the moment every axis of the segment before it is in position
(``SegmentGate``), or, at a corner every drive can blend, as the axes come within
``blend`` of the corner. The report gives each segment's planned duration, how tightly
the axes arrived and how far the path strays from the straight segment, predicted from
the plans the drives took (their trajectories from the moments they took them).
"""

from __future__ import annotations

import bisect
import math
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass, replace
from typing import TYPE_CHECKING, Any, Literal, Protocol

import anyio
import anyio.lowlevel

from drivebus import checks
from drivebus.errors import ArgumentError, DrivebusError, GroupMotionError, StateError
from drivebus.motion import planning
from drivebus.motion.envelope import MotionPlan
from drivebus.motion.gate import SegmentGate
from drivebus.motion.handle import BufferMode, MotionHandle
from drivebus.motion.planning import GroupPlan, StartGate
from drivebus.motion.trajectory import Trajectory
from drivebus.tasks import shielded

if TYPE_CHECKING:
    from drivebus.motion.axis import Axis


class Group(Protocol):
    """What a path reads of its group (an ``Group``)."""

    axes: dict[str, Axis]

    def checked(self, values: Mapping[str, float], what: str, *, free: bool = True
                ) -> dict[str, float]: ...
    async def positions(self, names: Iterable[str]) -> dict[str, float]: ...
    def stops(self, names: Iterable[str]) -> dict[str, int]: ...
    def check_not_stopped(self, before: Mapping[str, int], what: str) -> None: ...
    def started(self, names: Iterable[str]) -> dict[str, float]: ...
    def check_not_started(self, before: Mapping[str, float], what: str) -> None: ...
    def start_gate(self, plan: GroupPlan) -> StartGate: ...
    async def stop(self) -> None: ...

__all__ = ["GroupHandle", "PathReport", "SegmentReport"]

_SAMPLES = 200
"""Moments a segment's predicted path is looked at (besides its phase boundaries)."""
_SAMPLES_PER_TURN = 50
"""Moments of a segment or a blend looked at per event-loop turn (about 1-2 ms of CPU)."""
_LEAST_BLEND = 0.002
"""A corner blended less than this long before its end is not worth it, seconds."""

SegmentEnd = Literal["stop", "blend", "end"]


@dataclass(frozen=True)
class SegmentReport:
    """One straight segment of a path, as planned and as it ran."""

    index: int
    """1 for the first segment."""
    start: dict[str, float]
    end: dict[str, float]
    duration: float
    """Planned time from its start to its arrival (at rest), seconds."""
    plans: dict[str, MotionPlan]
    ends: SegmentEnd
    """``stop``: every axis stopped in position before the next (buffered); ``blend``:
    the next took over on the fly before the corner; ``end``: the path's last."""
    reason: str
    """Why the corner after it was not blended ("" if it was, or it is the last)."""
    planned_arrival_spread: float
    """Spread of the moving axes' planned arrivals (from the moments the drives took
    their moves), seconds."""
    observed_arrival_spread: float
    """Spread of the arrivals the polls saw (each the middle of the window between the
    poll that saw it and the one before), or of the moments a blend took over, seconds."""
    max_deviation: float
    """The farthest the axes' planned trajectories stray from the path's straight
    segments (this one and its neighbours) while it runs, in the axes' units: start and
    arrival skew, and the corners' cut where they blend."""
    dwell: float
    """Planned standstill between its last axis's arrival and the next segment's first
    start (0 for a blend or the last), seconds."""


@dataclass(frozen=True)
class PathReport:
    """A path's segments, as planned and as they ran."""

    segments: tuple[SegmentReport, ...]
    duration: float
    """From the first start to the last arrival, as the drives were planned, seconds."""

    @property
    def max_deviation(self) -> float:
        """The largest deviation from a straight segment along the whole path."""
        return max((s.max_deviation for s in self.segments), default=0.0)


class GroupHandle:
    """A group move queued with a buffer mode: ``await`` it for its report (a
    ``PathReport`` of one segment); ``await handle.cancel()`` stops every axis of it."""

    def __init__(self, group: Group, run: _PathRun) -> None:
        self.group = group
        self._run = run

    @property
    def handles(self) -> dict[str, MotionHandle]:
        """Each moving axis's handle."""
        return dict(self._run.handles[0])

    @property
    def done(self) -> bool:
        """True once every axis's part is over."""
        return all(h.done for h in self._run.handles[0].values())

    async def wait(self) -> PathReport:
        """Return the report once every axis is there; ``GroupMotionError`` naming the
        first axis that failed (every axis of the group is stopped then)."""
        return await self._run.finish()

    def __await__(self) -> Any:
        return self.wait().__await__()

    async def cancel(self) -> None:
        """Stop every axis of the group and drop their queues."""
        await self.group.stop()


@dataclass
class _PathRun:
    """A path (or a queued group move) whose parts are queued on the axes."""

    group: Group
    points: list[dict[str, float]]
    plans: list[GroupPlan]
    taus: list[float | None]
    reasons: list[str]
    handles: list[dict[str, MotionHandle]]

    async def finish(self) -> PathReport:
        """Await every part; on the first failure (or a cancellation) stop every axis once,
        raise it named."""
        failure: list[tuple[str, BaseException]] = []

        async def one(name: str, handles: list[MotionHandle], scope: anyio.CancelScope
                      ) -> None:
            # An axis's parts are queued on it in order, and a failure of any of them (or
            # a stop) drops its queue: its last part ends then, failed. So one wait per
            # axis sees a failure at once. (A task per part was some 60 objects a
            # waypoint and axis for the collector to scan, and cancelled, each part's own
            # wait stopped its axis: a stop a waypoint.) A cancellation here waits for
            # nothing: the group's one stop below ends them all.
            last = handles[-1]
            await last.ended()
            failed = next((h for h in handles if h.error is not None), None)
            try:
                await (failed or last)  # the first failure; or the status after the end
            except DrivebusError as exc:
                if not failure:
                    failure.append((name, exc))
                scope.cancel()

        by_axis: dict[str, list[MotionHandle]] = {}
        for parts in self.handles:
            for name, handle in parts.items():
                by_axis.setdefault(name, []).append(handle)
        try:
            async with anyio.create_task_group() as tg:
                for name, handles in by_axis.items():
                    tg.start_soon(one, name, handles, tg.cancel_scope)
        finally:
            if failure or not all(h.done for p in self.handles for h in p.values()):
                await shielded(self.group.stop)
        if failure:
            name, exc = failure[0]
            raise GroupMotionError(f"axis {name} failed, the group was stopped: {exc}",
                                   axis=name) from exc
        return await report(self)


async def run_path(
    group: Group,
    waypoints: Sequence[Mapping[str, float]],
    *,
    speed: float | None,
    accel: float | None,
    decel: float | None,
    blend: float,
) -> PathReport:
    """``AxisGroup.path``: plan, queue, start, await, report (see there)."""
    blend = checks.finite("blend", blend)
    if blend < 0:
        raise ArgumentError(f"blend: {blend:g} is below 0 (a distance in the axes' units)")
    if isinstance(waypoints, Mapping) or not waypoints:
        raise ArgumentError("a path needs a list of waypoints (mappings of axis to position)")
    names = list(group.axes)
    checked = [group.checked(wp, f"waypoint {i + 1}") for i, wp in enumerate(waypoints)]
    stops, started = group.stops(names), group.started(names)
    points = [await group.positions(names)]
    for i, wp in enumerate(checked):
        point = {**points[-1], **wp}
        for n, v in wp.items():
            group.axes[n].check_limits(v)
        if point == points[-1]:
            raise ArgumentError(f"waypoint {i + 1} is where the path already is")
        points.append(point)
    plans: list[GroupPlan] = []
    for k in range(len(points) - 1):
        movers = [n for n in names if points[k + 1][n] != points[k][n]]
        plans.append(await planning.plan(group.axes,
            {n: points[k + 1][n] for n in movers}, {n: points[k][n] for n in movers},
            speed=speed, accel=accel, decel=decel,
            offsets=None if k == 0 else dict.fromkeys(movers, 0.0)))
        group.check_not_stopped(stops, "path")  # a stop meanwhile: no more planning
    taus: list[float | None] = [None]
    reasons: list[str] = []
    ahead = _from_rest(group, plans[0], 0.0)
    for k in range(1, len(plans)):
        await anyio.lowlevel.checkpoint()  # a long path's corners: no long hold of the loop
        tau, reason = await _corner(group, ahead, plans[k - 1], plans[k], blend)
        taus.append(tau)
        reasons.append(reason)
        group.check_not_stopped(stops, "path")
        if tau is None:
            ahead = _from_rest(group, plans[k], max(t.end for t in ahead.values()))
        else:
            ahead = _synchronise_blend(group, ahead, plans[k], tau)
    reasons.append("")
    group.check_not_stopped(stops, "path")
    group.check_not_started(started, "path")
    for n in names:
        group.axes[n].check_free("path")
    run = _PathRun(group, points, plans, taus, reasons, [])
    gate = group.start_gate(plans[0])
    await _queue_and_start(run, gate)
    return await run.finish()


async def queue_group_move(
    group: Group,
    targets: Mapping[str, float],
    buffer: BufferMode,
    accepted: Any,
    *,
    stops: Mapping[str, int],
    **shape: float | None,
) -> GroupHandle:
    """``AxisGroup.move_to`` with a buffer mode: one segment queued behind what the
    group's axes do (from rest: started through the start gate at once). Buffered, it
    starts once every busy axis of the group is done; blending, where every moving axis
    is busy and can blend, each takes its target as it begins to brake."""
    axes = group.axes
    starts: dict[str, float] = {}
    for n in targets:
        end = axes[n].planned_end
        if end is None:
            raise StateError(f"axis {n}: the group move cannot be queued: the motion under "
                             f"way has no end position")
        starts[n] = end
    busy = [n for n in targets if axes[n].busy]
    for n in targets:
        if n not in busy:
            axes[n].check_free("group move")
    movers = {n: t for n, t in targets.items() if t != starts[n]}
    if not movers:
        raise ArgumentError("every axis of the group move is at its target already")
    plan = await planning.plan(group.axes, movers, {n: starts[n] for n in movers},
                       offsets=None if not busy else dict.fromkeys(movers, 0.0),
                       **shape)  # type: ignore[arg-type]
    group.check_not_stopped(stops, "group move")
    reason = ""
    if buffer == "blending":
        for n in movers:
            why = (axes[n].blend_problem(movers[n]) if n in busy
                   else "it is at rest: a group blends only axes that all move")
            if why:
                reason = f"axis {n}: {why}"
                break
    run = _PathRun(group, [dict(starts), {**starts, **movers}], [plan], [None], [reason], [])
    if accepted is not None:
        accepted()
    if not busy:
        await _queue_and_start(run, group.start_gate(plan))
        return GroupHandle(group, run)
    before = SegmentGate(busy)
    for n in busy:
        if not axes[n].report_to(before):
            before.arrive(n, 0.0)
    blended = buffer == "blending" and not reason
    run.handles.append({
        n: axes[n].queue_segment("group move", movers[n], plan.plans[n], origin=starts[n],
                                 gate=None if blended else before, blend=blended)
        for n in movers})
    return GroupHandle(group, run)


async def _queue_and_start(run: _PathRun, gate: StartGate) -> None:
    """Queue every segment's parts, open the start gate once every first part is
    written; a part that fails before the gate opens stops the lot."""
    group, plans = run.group, run.plans
    gates = [SegmentGate(list(p.targets)) for p in plans]
    try:
        for k, plan in enumerate(plans):
            await anyio.lowlevel.checkpoint()  # a long path: no long hold of the loop
            tau = run.taus[k]
            parts: dict[str, MotionHandle] = {}
            for n, target in plan.targets.items():
                parts[n] = group.axes[n].queue_segment(
                    f"path segment {k + 1}" if len(plans) > 1 else "group move",
                    target, plan.plans[n], origin=plan.starts[n],
                    gate=None if k == 0 or tau is not None else gates[k - 1],
                    reports=gates[k], blend_before_end=tau,
                    ready=(lambda n=n: gate.ready(n)) if k == 0 else None)
            run.handles.append(parts)
        async with anyio.create_task_group() as tg:

            async def watch(handle: MotionHandle) -> None:
                await handle.ended()  # before the gate opens only if it failed
                if handle.error is not None:
                    tg.cancel_scope.cancel()

            for handle in run.handles[0].values():
                tg.start_soon(watch, handle)
            await gate.open()
            tg.cancel_scope.cancel()
    except BaseException:
        await shielded(group.stop)
        raise


def _from_rest(group: Group, plan: GroupPlan, t0: float) -> dict[str, Trajectory]:
    """``plan``'s axes' trajectories from rest at ``t0`` (a buffered segment's start)."""
    return {n: Trajectory.point_to_point(plan.starts[n], plan.targets[n],
                                         group.axes[n].envelope.quantized(plan.plans[n]),
                                         t0=t0 + plan.offsets.get(n, 0.0))
            for n in plan.targets}


def _synchronise_blend(
    group: Group, before: dict[str, Trajectory], after: GroupPlan, tau: float
) -> dict[str, Trajectory]:
    """Give each axis of a blended segment the speed at which it arrives with the slowest
    (each takes its new target ``tau`` before it would arrive, from the speed it has
    then); ``after.plans`` is updated, and the predicted trajectories returned."""
    axes = group.axes

    def blended(n: str, plan: MotionPlan) -> Trajectory:
        t = before[n]
        return t.retargeted(t.end - tau, after.targets[n], axes[n].envelope.quantized(plan))

    common = max(blended(n, after.plans[n]).end for n in after.targets)
    out: dict[str, Trajectory] = {}
    for n, plan in after.plans.items():
        lo, hi = plan.speed * 0.05, plan.speed
        for _ in range(40):  # slower cruise, later arrival
            mid = (lo + hi) / 2
            lo, hi = (mid, hi) if blended(n, replace(plan, speed=mid)).end > common else (lo, mid)
        fitted = replace(plan, speed=hi)
        try:
            axes[n].check_drive(fitted)
        except DrivebusError:
            fitted = plan
        after.plans[n] = fitted
        out[n] = blended(n, fitted)
    return out


async def _corner(
    group: Group, first: dict[str, Trajectory], before: GroupPlan, after: GroupPlan,
    blend: float,
) -> tuple[float | None, str]:
    """How long before the end of ``before`` (its axes predicted to run ``first``) the axes
    take ``after``'s targets so that the path passes within ``blend`` of the corner (None:
    the corner stops), and why not."""
    if blend <= 0:
        return None, "blend is 0: the path stops at its corners"
    for n in group.axes:
        if n not in before.targets or n not in after.targets:
            return None, f"axis {n} does not move on both sides of the corner"
        support = group.axes[n].profile.programs
        if not support.blends:
            return None, (f"axis {n}: the {group.axes[n].profile.family} drive cannot take a "
                          f"new target while it moves: {support.no_retarget}")
    quantized = {n: group.axes[n].envelope.quantized for n in group.axes}
    corner = before.targets
    longest = min(t.end - t.braking_starts() for t in first.values())

    lines = [(before.starts, corner), (corner, after.targets)]

    async def cut(tau: float) -> float:
        """How far the path strays from the two straight segments when blended ``tau``
        before the corner."""
        trajectories = {
            n: first[n].retargeted(first[n].end - tau, after.targets[n],
                                   quantized[n](after.plans[n])) for n in group.axes}
        t0 = min(t.end for t in first.values()) - tau
        t1 = max(t.end for t in trajectories.values())
        return await _farthest(
            lambda t: {n: tr.position(t) for n, tr in trajectories.items()},
            _moments(t0, t1), lines)

    if await cut(longest) <= blend:
        tau = longest
    else:
        lo, hi = 0.0, longest
        for _ in range(30):
            mid = (lo + hi) / 2
            lo, hi = (mid, hi) if await cut(mid) <= blend else (lo, mid)
        tau = lo
    if tau < _LEAST_BLEND:
        return None, f"the corner is too sharp to blend within {blend:g}"
    return tau, ""


def _moments(t0: float, t1: float) -> list[float]:
    return [t0 + (t1 - t0) * i / _SAMPLES for i in range(_SAMPLES + 1)]


def _distance(p: Mapping[str, float], q: Mapping[str, float]) -> float:
    return math.sqrt(sum((p[n] - q[n]) ** 2 for n in q))


def _off_segment(p: Mapping[str, float], a: Mapping[str, float], b: Mapping[str, float]
                 ) -> float:
    """Distance of point ``p`` from the straight segment ``a``-``b``."""
    ab = {n: b[n] - a[n] for n in a}
    length2 = sum(v * v for v in ab.values())
    if length2 == 0:
        return _distance(p, a)
    s = max(0.0, min(1.0, sum((p[n] - a[n]) * ab[n] for n in a) / length2))
    return _distance(p, {n: a[n] + s * ab[n] for n in a})


async def _farthest(point: Callable[[float], Mapping[str, float]], moments: Sequence[float],
                    lines: Sequence[tuple[Mapping[str, float], Mapping[str, float]]]
                    ) -> float:
    """How far the axes, at ``point(t)``, stray from the straight segments ``lines`` at
    ``moments`` (``_SAMPLES_PER_TURN`` moments per event-loop turn)."""
    farthest = 0.0
    for i, t in enumerate(moments):
        if i and i % _SAMPLES_PER_TURN == 0:
            await anyio.lowlevel.checkpoint()
        farthest = max(farthest, _off_path(point(t), lines))
    return farthest


def _off_path(p: Mapping[str, float],
              lines: Sequence[tuple[Mapping[str, float], Mapping[str, float]]]) -> float:
    """Distance of ``p`` from the nearest of the straight segments ``lines``."""
    return min(_off_segment(p, a, b) for a, b in lines)


async def report(run: _PathRun) -> PathReport:
    """The path's report from its plans and the trajectories its parts ran (computed a
    segment per event-loop turn: a long path's report holds nothing up)."""
    names = list(run.group.axes)
    timeline: dict[str, list[tuple[float, Trajectory]]] = {n: [] for n in names}
    for parts in run.handles:
        for n, h in parts.items():
            if h.began is not None and h.trajectory is not None:
                timeline[n].append((h.began, h.trajectory))
    for n in names:
        timeline[n].sort(key=lambda bt: bt[0])
    starts = {n: [began for began, _ in timeline[n]] for n in names}

    def where(n: str, t: float, k: int) -> float:
        i = bisect.bisect_right(starts[n], t)
        return timeline[n][i - 1][1].position(t) if i else run.points[k][n]

    segments: list[SegmentReport] = []
    first_start = math.inf
    last_end = 0.0
    for k, (plan, parts) in enumerate(zip(run.plans, run.handles, strict=True)):
        await anyio.lowlevel.checkpoint()
        began = [h.began for h in parts.values() if h.began is not None]
        ends = {n: h.trajectory.end for n, h in parts.items() if h.trajectory is not None}
        nxt = run.handles[k + 1] if k + 1 < len(run.handles) else {}
        blended = k + 1 < len(run.taus) and run.taus[k + 1] is not None
        start = min(began, default=0.0)
        stop = max(ends.values(), default=start)
        next_began = [h.began for h in nxt.values() if h.began is not None]
        window_end = min(next_began) if blended and next_began else stop
        a, b = run.points[k], run.points[k + 1]
        lines = [(run.points[i], run.points[i + 1])
                 for i in range(max(0, k - 1), min(len(run.points) - 1, k + 2))]
        deviation = await _farthest(lambda t, k=k: {n: where(n, t, k) for n in names},
                                    _moments(start, window_end), lines)
        if blended:
            observed = _spread(next_began)
        else:
            arrived = [(h.arrived[0] + h.arrived[1]) / 2 for h in parts.values()
                       if h.arrived is not None]
            observed = _spread(arrived)
        dwell = max(0.0, min(next_began) - stop) if next_began and not blended else 0.0
        first_start, last_end = min(first_start, start), max(last_end, stop)
        segments.append(SegmentReport(
            k + 1, dict(a), dict(b), plan.total, dict(plan.plans),
            "end" if k == len(run.plans) - 1 else "blend" if blended else "stop",
            run.reasons[k] if k < len(run.reasons) else "",
            _spread(list(ends.values())), observed, deviation, dwell))
    return PathReport(tuple(segments), max(0.0, last_end - first_start))


def _spread(values: list[float]) -> float:
    return max(values) - min(values) if values else 0.0
