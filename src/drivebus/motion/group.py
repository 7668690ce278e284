"""AxisGroup: several axes moved together so that they start and arrive together.

The commands (``move_to``, ``move_by``, ``path``, ``home``, ``stop``) and the report of a
group move; how a synchronised move is planned and started is ``drivebus.motion.planning``,
a path and a queued group move ``drivebus.motion.path``. A stop of any of the axes while
a command plans aborts it before anything starts.
"""

from __future__ import annotations

from collections.abc import Awaitable, Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass, field

import anyio
import anyio.lowlevel

from drivebus import checks
from drivebus.errors import (
    ArgumentError,
    DrivebusError,
    GroupMotionError,
    MotionAborted,
    StateError,
)
from drivebus.motion import planning
from drivebus.motion.axis import Axis, MotionPlan
from drivebus.motion.handle import BufferMode, check_buffer
from drivebus.motion.path import GroupHandle, PathReport, queue_group_move, run_path
from drivebus.motion.planning import GroupPlan, StartGate, synchronise

__all__ = ["AxisGroup", "GroupMotionError", "GroupMoveReport", "synchronise"]


@dataclass(frozen=True)
class GroupMoveReport:
    """What a synchronised move planned, how tightly the axes started and arrived.

    Only the axes that moved count in the skew and the spreads (an axis already at its
    target arrives at once and says nothing of the others). The planned arrivals follow
    from the accepted starts and the plans; the observed ones from the first poll that
    saw each axis in position (up to its reply) and the poll before it (which saw it still
    on its way, from when it was sent): each is the middle of that window, so known only
    to within ``observed_resolution``. The drives themselves may arrive much closer
    together than the observed spread can show.
    """

    duration: float
    """Planned time from the first start to the common arrival, seconds."""
    start_skew: float
    """Time between the first and the last moving axis's start being accepted, seconds."""
    plans: dict[str, MotionPlan]
    observed_arrival_spread: float = 0.0
    """Time between the first and the last moving axis seen in position by its polls,
    seconds (each known to within ``observed_resolution``)."""
    start_offsets: dict[str, float] | None = None
    """Each axis's predicted start delay behind the first start, seconds."""
    planned_arrival_spread: float = 0.0
    """Spread of the moving axes' planned arrivals (accepted start + plan), seconds."""
    observed_resolution: float = 0.0
    """The widest window between the poll that saw an axis arrived and the one before it,
    seconds: how finely the observed arrivals (and their spread) are known."""
    planned_arrivals: dict[str, float] = field(default_factory=dict)
    """Each moving axis's planned arrival, seconds after the first accepted start."""
    observed_arrivals: dict[str, float] = field(default_factory=dict)
    """Each moving axis's arrival as its polls saw it, seconds after the first start."""

    @property
    def arrival_spread(self) -> float:
        """The observed arrival spread (``observed_arrival_spread``), seconds."""
        return self.observed_arrival_spread


class AxisGroup:
    """Axes of one machine commanded together: ``machine.group("x", "y")``."""

    def __init__(self, axes: Sequence[Axis]) -> None:
        if not axes:
            raise ArgumentError("a group needs at least one axis")
        self.axes = {a.name: a for a in axes}
        self.last_report: GroupMoveReport | None = None

    def checked(self, values: Mapping[str, float], what: str, *, free: bool = True
               ) -> dict[str, float]:
        unknown = set(values) - set(self.axes)
        if unknown:
            raise ArgumentError(
                f"axes {', '.join(sorted(unknown))} are not in this group "
                f"({', '.join(self.axes)})"
            )
        if not values:
            raise ArgumentError(f"{what}: no axes given")
        checked = {n: checks.finite(f"axis {n}: {what} {n!r}", v) for n, v in values.items()}
        for n in checked:  # each axis moves by absolute moves: one that cannot is refused now
            self.axes[n].profile.check_supported("move_absolute")
        if free:
            for n in checked:
                self.axes[n].check_free("group move")
        return checked

    def stops(self, names: Iterable[str]) -> dict[str, int]:
        """How many stops each named axis has had (``Axis.stops``): a command that plans
        before it takes its axes notes them first and calls ``check_not_stopped`` after."""
        return {n: self.axes[n].stops for n in names}

    def check_not_stopped(self, before: Mapping[str, int], what: str) -> None:
        """``MotionAborted`` if an axis was stopped since ``before`` (``stops``): a stop
        issued while a command is planned wins, and the command starts nothing."""
        for n, count in before.items():
            if self.axes[n].stops != count:
                raise MotionAborted(f"the {what} was aborted: axis {n} was stopped while it "
                                    f"was being planned")

    def started(self, names: Iterable[str]) -> dict[str, float]:
        """When each named axis last started a motion: a command that plans from where
        its axes are notes it first and calls ``check_not_started`` after."""
        return {n: self.axes[n].command_started_at for n in names}

    def check_not_started(self, before: Mapping[str, float], what: str) -> None:
        """``StateError`` if an axis started another motion since ``before`` (``started``):
        the plan was made from where it no longer is, and nothing of it starts."""
        for n, at in before.items():
            if self.axes[n].command_started_at != at:
                raise StateError(f"the {what} was refused: axis {n} started another motion "
                                 f"while it was being planned, from where it no longer is")

    async def positions(self, names: Iterable[str]) -> dict[str, float]:
        """The named axes' present positions (user units), read from the drives at once."""
        found: dict[str, float] = {}

        async def read(axis: Axis) -> None:
            st = await axis.refresh()
            found[axis.name] = axis.units.from_pulses(st.position or 0)

        await self._each([self.axes[n] for n in names], read)
        return found

    async def move_to(
        self,
        targets: Mapping[str, float],
        *,
        speed: float | None = None,
        accel: float | None = None,
        decel: float | None = None,
        duration: float | None = None,
        buffer: BufferMode = "aborting",
        accepted: Callable[[], object] | None = None,
    ) -> GroupMoveReport | GroupHandle:
        """Move the named axes to their targets, starting and arriving together.

        By default every axis runs at most at its own speed and ramps and the slowest sets
        the pace. ``speed``, ``accel``, ``decel``: along the straight line between the two
        points, in the axes' common unit (each axis gets its share); ``duration``: the move
        takes that long (``LimitViolation`` naming the axis that cannot). ``buffer``:
        ``"buffered"`` or ``"blending"`` queue it behind what the axes are doing (a
        ``GroupHandle`` is returned: await it for the segment's report), as for an axis.

        ``accepted()`` is called once every check has passed and every plan fits its drive,
        just before the axes take their moves."""
        buffer = check_buffer(buffer)
        targets = self.checked(targets, "targets", free=buffer == "aborting")
        for name, t in targets.items():
            self.axes[name].check_limits(t)
        shape = {"speed": speed, "accel": accel, "decel": decel, "duration": duration}
        stops = self.stops(targets)
        if buffer != "aborting":
            return await queue_group_move(self, targets, buffer, accepted, stops=stops,
                                          **shape)
        started = self.started(targets)
        return await self._move(targets, await self.positions(targets), accepted,
                                stops=stops, started=started, **shape)

    async def move_by(
        self,
        distances: Mapping[str, float],
        *,
        speed: float | None = None,
        accel: float | None = None,
        decel: float | None = None,
        duration: float | None = None,
        accepted: Callable[[], object] | None = None,
    ) -> GroupMoveReport:
        """Move the named axes by their distances, together (the rest: as for
        ``move_to``)."""
        distances = self.checked(distances, "distances")
        stops, started = self.stops(distances), self.started(distances)
        starts = await self.positions(distances)
        targets = {n: starts[n] + d for n, d in distances.items()}
        for name, t in targets.items():
            self.axes[name].check_limits(t)
        return await self._move(targets, starts, accepted, stops=stops, started=started,
                                speed=speed, accel=accel, decel=decel, duration=duration)

    async def path(
        self,
        waypoints: Sequence[Mapping[str, float]],
        *,
        speed: float | None = None,
        accel: float | None = None,
        decel: float | None = None,
        blend: float = 0.0,
    ) -> PathReport:
        """Move through ``waypoints`` (each names the axes that change; the others keep
        their place), one synchronised straight segment after another, from rest; returns
        once the last is reached. ``speed``/``accel``/``decel``: along each segment, as for
        ``move_to``. ``blend``: how far (axes' units) the path may leave a corner: corners
        are blended within it where every axis's drive takes a new target on the fly, and
        the report says where and why not. Each segment starts the moment the one before
        it is in position (no poll period lost), or blends. A failure or cancellation
        stops every axis and drops the rest of the path."""
        return await run_path(self, waypoints, speed=speed, accel=accel, decel=decel,
                              blend=blend)

    async def _plan(self, targets: Mapping[str, float], starts: Mapping[str, float],
                    **shape: object) -> GroupPlan:
        """The group's synchronised plan (``drivebus.motion.planning.plan``)."""
        return await planning.plan(self.axes, targets, starts, **shape)  # type: ignore[arg-type]

    def start_gate(self, plan: GroupPlan) -> StartGate:
        """The gate that starts ``plan``'s axes back to back on their held lines."""
        return planning.start_gate(self.axes, plan)

    async def _move(
        self,
        targets: Mapping[str, float],
        starts: Mapping[str, float],
        accepted: Callable[[], object] | None = None,
        *,
        stops: Mapping[str, int],
        started: Mapping[str, float],
        **shape: float | None,
    ) -> GroupMoveReport:
        plan = await self._plan(targets, starts, **shape)  # type: ignore[arg-type]
        plans, offsets, distances = plan.plans, plan.offsets, plan.distances
        gate = self.start_gate(plan)
        self.check_not_stopped(stops, "group move")
        self.check_not_started(started, "group move")
        for n in targets:
            self.axes[n].check_free("group move")
        if accepted is not None:
            accepted()

        async def move(axis: Axis) -> None:
            p = plans[axis.name]
            await axis.move_to(targets[axis.name], speed=p.speed, accel=p.accel, decel=p.decel,
                               ready=lambda: gate.ready(axis.name))

        arrived: dict[str, tuple[float, float]] = {}

        async def move_and_note(axis: Axis) -> None:
            await move(axis)
            arrived[axis.name] = (axis.arrived_after, axis.arrived_by)

        await self._each([self.axes[n] for n in targets], move_and_note, also=gate.open)
        report = self._report(plan.total, plans, offsets, distances, arrived)
        self.last_report = report
        return report

    def _report(
        self,
        total: float,
        plans: dict[str, MotionPlan],
        offsets: dict[str, float],
        distances: Mapping[str, float],
        arrived: Mapping[str, tuple[float, float]],
    ) -> GroupMoveReport:
        """The figures of a finished group move, from the axes that moved."""
        moved = [n for n in distances if distances[n] != 0 and n in arrived]
        if not moved:
            return GroupMoveReport(total, 0.0, plans, 0.0, offsets)
        started = {n: self.axes[n].command_started_at for n in moved}
        t0 = min(started.values())
        planned = {n: started[n] - t0 + plans[n].duration(distances[n]) for n in moved}
        observed = {n: (arrived[n][0] + arrived[n][1]) / 2 - t0 for n in moved}

        def spread(values: Iterable[float]) -> float:
            v = list(values)
            return max(v) - min(v)

        return GroupMoveReport(
            total,
            spread(started.values()),
            plans,
            spread(observed.values()),
            offsets,
            planned_arrival_spread=spread(planned.values()),
            observed_resolution=max(arrived[n][1] - arrived[n][0] for n in moved),
            planned_arrivals=planned,
            observed_arrivals=observed,
        )

    async def home(self) -> None:
        """Home every axis of the group in parallel."""
        await self._each(list(self.axes.values()), lambda a: a.home())

    async def stop(self) -> None:
        """Stop every axis of the group in parallel."""
        await self._each(list(self.axes.values()), lambda a: a.stop())

    async def _each(
        self,
        axes: Sequence[Axis],
        fn: Callable[[Axis], Awaitable[None]],
        *,
        also: Callable[[], Awaitable[None]] | None = None,
    ) -> None:
        """Run ``fn`` on every axis at once (and ``also``); the first failure stops the
        rest and is raised as a ``GroupMotionError`` naming its axis."""
        failure: list[tuple[str, BaseException]] = []

        async def one(axis: Axis, scope: anyio.CancelScope) -> None:
            try:
                await fn(axis)
            except DrivebusError as exc:
                if not failure:
                    failure.append((axis.name, exc))
                scope.cancel()  # the others' motions are cancelled: each stops its axis

        async def helper(scope: anyio.CancelScope) -> None:
            assert also is not None
            try:
                await also()
            except DrivebusError as exc:
                if not failure:
                    failure.append(("(group)", exc))
                scope.cancel()

        async with anyio.create_task_group() as tg:
            for a in axes:
                tg.start_soon(one, a, tg.cancel_scope)
            if also is not None:
                tg.start_soon(helper, tg.cancel_scope)
        if failure:
            name, exc = failure[0]
            raise GroupMotionError(f"axis {name} failed, the group was stopped: {exc}",
                                   axis=name) from exc
