"""AxisGroup: several axes moved together so that they start and arrive together."""

from __future__ import annotations

import math
from collections.abc import Awaitable, Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass

import anyio

from drivebus.errors import DrivebusError, LimitViolation
from drivebus.motion.axis import Axis, MotionPlan

__all__ = ["AxisGroup", "GroupMotionError", "GroupMoveReport", "synchronise"]


class _TooShort(Exception):
    """A planned group duration is too short for one axis's own ramps."""


class _Barrier:
    """Every axis prepares its move, then all start together (the starts go back to back)."""

    def __init__(self, parties: int) -> None:
        self._left = parties
        self._all_in = anyio.Event()

    async def wait(self) -> None:
        self._left -= 1
        if self._left <= 0:
            self._all_in.set()
        await self._all_in.wait()


class GroupMotionError(DrivebusError):
    """One axis of a group failed; the others were stopped. ``axis`` names the culprit."""

    def __init__(self, message: str, *, axis: str) -> None:
        super().__init__(message)
        self.axis = axis


@dataclass(frozen=True)
class GroupMoveReport:
    """What a synchronised move planned and how tightly the axes started."""

    duration: float
    """Planned time from start to arrival, seconds."""
    start_skew: float
    """Time between the first and the last axis's start command being accepted, seconds."""
    plans: dict[str, MotionPlan]


def synchronise(
    distances: Mapping[str, float],
    limits: Mapping[str, MotionPlan],
    min_duration: float = 0.0,
) -> tuple[float, dict[str, MotionPlan]]:
    """Per-axis plans so every axis covers its distance in the same time, same ramp fractions.

    The slowest axis at its own limits sets the duration and the ramp times; the others
    scale speed and ramps down to match, and the duration grows if any would exceed its
    own limits.
    """
    moving = {n: abs(d) for n, d in distances.items() if d != 0}
    if not moving:
        return 0.0, {n: limits[n] for n in distances}
    lead = max(moving, key=lambda n: limits[n].duration(moving[n]))
    lp, ld = limits[lead], moving[lead]
    total = lp.duration(ld)
    peak = min(lp.speed, math.sqrt(2 * ld * lp.accel * lp.decel / (lp.accel + lp.decel)))
    t_acc, t_dec = peak / lp.accel, peak / lp.decel
    if min_duration > total:  # stretch: same ramp times, every axis cruises slower
        total = min_duration
    for _ in range(200):
        cruise = total - (t_acc + t_dec) / 2
        plans = {}
        fits = True
        for n, d in moving.items():
            v = d / cruise
            plan = MotionPlan(v, v / t_acc, v / t_dec)
            lim = limits[n]
            if (plan.speed > lim.speed * 1.000001 or plan.accel > lim.accel * 1.000001
                    or plan.decel > lim.decel * 1.000001):
                fits = False
            plans[n] = plan
        if fits:
            break
        total *= 1.05
        t_acc *= 1.05
        t_dec *= 1.05
    for n in distances:
        plans.setdefault(n, limits[n])
    return total, plans


class AxisGroup:
    """Axes of one machine commanded together: ``machine.group("x", "y")``."""

    def __init__(self, axes: Sequence[Axis]) -> None:
        if not axes:
            raise ValueError("a group needs at least one axis")
        self.axes = {a.name: a for a in axes}
        self.last_report: GroupMoveReport | None = None

    def _check_names(self, targets: Mapping[str, float]) -> None:
        unknown = set(targets) - set(self.axes)
        if unknown:
            raise DrivebusError(
                f"axes {', '.join(sorted(unknown))} are not in this group "
                f"({', '.join(self.axes)})"
            )

    async def _positions(self, names: Iterable[str]) -> dict[str, float]:
        """The named axes' present positions (user units), read from the drives at once."""
        found: dict[str, float] = {}

        async def read(axis: Axis) -> None:
            st = await axis._fresh_status()
            found[axis.name] = axis.units.from_pulses(st.position or 0)

        await self._each([self.axes[n] for n in names], read)
        return found

    async def move_to(self, targets: Mapping[str, float]) -> GroupMoveReport:
        """Move the named axes to their targets, starting and arriving together."""
        self._check_names(targets)
        return await self._move(targets, await self._positions(targets))

    async def _move(
        self, targets: Mapping[str, float], starts: Mapping[str, float]
    ) -> GroupMoveReport:
        for name, t in targets.items():
            self.axes[name].check_limits(t)
        distances = {n: targets[n] - starts[n] for n in targets}
        limits = {n: self.axes[n].plan() for n in targets}
        duration, plans = synchronise(distances, limits)
        for _ in range(50):  # every plan is checked before any axis moves
            try:
                plans = {
                    n: self._drive_ready(self.axes[n], distances[n], duration, plans[n])
                    for n in targets
                }
                break
            except _TooShort:
                duration, plans = synchronise(distances, limits, duration * 1.1)
        else:
            raise LimitViolation("group move: no common duration fits every drive's ramps")

        barrier = _Barrier(len(targets))

        async def move(axis: Axis) -> None:
            p = plans[axis.name]
            await axis.move_to(targets[axis.name], speed=p.speed, accel=p.accel, decel=p.decel,
                               ready=barrier.wait)

        await self._each([self.axes[n] for n in targets], move)
        times = [self.axes[n].command_started_at for n in targets]
        report = GroupMoveReport(duration, max(times) - min(times), plans)
        self.last_report = report
        return report

    @staticmethod
    def _drive_ready(axis: Axis, distance: float, duration: float, plan: MotionPlan) -> MotionPlan:
        """``plan`` if the drive takes it; else the same duration with the axis's own ramps.

        Scaling an axis down to the lead's ramp fractions can ask for a ramp below what
        its drive can do (a minimum acceleration, a longest ramp time). Then it ramps at
        its configured rate and cruises slower, arriving at the same time.
        """
        try:
            axis.profile.check_move(axis.drive_params(plan))
            return plan
        except LimitViolation:
            own = axis.plan()
        d = abs(distance)
        # d = v * (T - v/(2a) - v/(2b))  ->  v = (T - sqrt(T² - 2 d k)) / k, k = 1/(2a)+1/(2b)
        if d == 0:
            return own
        k = 1 / (2 * own.accel) + 1 / (2 * own.decel)
        disc = duration * duration - 4 * k * d
        if disc < 0:
            raise _TooShort  # even at its own ramps it cannot get there in time
        v = (duration - math.sqrt(disc)) / (2 * k)
        fallback = MotionPlan(v, own.accel, own.decel)
        axis.profile.check_move(axis.drive_params(fallback))  # raises, naming the register
        return fallback

    async def move_by(self, distances: Mapping[str, float]) -> GroupMoveReport:
        """Move the named axes by their distances, together."""
        self._check_names(distances)
        starts = await self._positions(distances)
        return await self._move({n: starts[n] + d for n, d in distances.items()}, starts)

    async def home(self) -> None:
        """Home every axis of the group in parallel."""
        await self._each(list(self.axes.values()), lambda a: a.home())

    async def stop(self) -> None:
        """Stop every axis of the group in parallel."""
        await self._each(list(self.axes.values()), lambda a: a.stop())

    async def _each(self, axes: Sequence[Axis], fn: Callable[[Axis], Awaitable[None]]) -> None:
        """Run ``fn`` on every axis at once; the first failure stops the rest and is raised."""
        failure: list[tuple[str, BaseException]] = []

        async def one(axis: Axis, scope: anyio.CancelScope) -> None:
            try:
                await fn(axis)
            except DrivebusError as exc:
                if not failure:
                    failure.append((axis.name, exc))
                scope.cancel()  # the others' motions are cancelled: each stops its axis

        async with anyio.create_task_group() as tg:
            for a in axes:
                tg.start_soon(one, a, tg.cancel_scope)
        if failure:
            name, exc = failure[0]
            raise GroupMotionError(f"axis {name} failed, the group was stopped: {exc}",
                                   axis=name) from exc
