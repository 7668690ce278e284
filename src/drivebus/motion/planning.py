"""Planning a synchronised move of several axes: cheap, exact to each drive, and never
holding the event loop.

Arriving together takes three things. Every axis is planned for the same duration with
the lead axis's ramp fractions (``synchronise``). Each plan is then fitted to what its
drive really runs: drives round speeds to whole rpm and ramps to whole r/s² or whole
milliseconds, which alone can shift a short, slow move by tens of milliseconds, so the
fit searches the drive's quantized values for the one closest to the duration
(``fit_plan``: a few hundred roundings through the move's register codecs, a range check
of the best, remembered per axis). And the start commands, which share lines, leave in a
known order while the group's lines are held quiet (``StartGate``), so each axis's start
delay behind the first is predicted from the wire timing (``start_order``) and taken off
its duration. ``plan`` gives the event loop a turn after each axis's fit.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping, Sequence
from contextlib import AsyncExitStack
from dataclasses import dataclass

import anyio
import anyio.lowlevel

from drivebus import checks
from drivebus.bus import Bus
from drivebus.clock import monotonic
from drivebus.errors import ArgumentError, LimitViolation
from drivebus.motion.axis import Axis, MotionPlan
from drivebus.settings import LineSettings
from drivebus.timing import switch_silence, timing

__all__ = ["GroupPlan", "StartGate", "fit_plan", "plan", "start_gate", "start_order",
           "synchronise"]

_START_FRAME = 8
"""Bytes of a start command and of its reply (an FC06 write on every seed drive)."""
_TURNAROUND = 0.001
"""Assumed reply delay of a drive to a start command, seconds."""
_ARRIVAL_TOLERANCE = 0.002
"""A planned arrival this close to the common one is good enough, seconds."""
_STRETCH_LIMIT = 0.05
"""A group is slowed by up to this (or 10 %) to suit a coarse-stepped drive; beyond it,
that drive's start is delayed instead, seconds."""
_HOLD_LEAD = 0.05
"""A delayed start holds its line this long before, so no poll is in flight then, seconds."""
_NETWORK_DELAY = 0.0003
"""Assumed delay of a start command on a Modbus TCP line, seconds."""
_FIT_MEMO = 512
"""Fits remembered per axis (``fit_plan``) before the memo starts afresh."""
_CANDIDATES_PER_TURN = 16
"""Candidate plans weighed per event-loop turn (each a rounding through the drive's
codecs, 50-100 us): about a millisecond of CPU between two turns."""


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
    plans: dict[str, MotionPlan] = {}
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


def _speed_for(distance: float, duration: float, accel: float, decel: float) -> float | None:
    """Cruise speed that covers ``distance`` in ``duration`` with these ramps (None: none)."""
    k = 1 / (2 * accel) + 1 / (2 * decel)
    disc = duration * duration - 4 * k * distance
    if disc < 0:
        return None
    return (duration - math.sqrt(disc)) / (2 * k)


async def fit_plan(
    axis: Axis, distance: float, duration: float, shape: MotionPlan, *, at_least: bool = False,
    ceiling: MotionPlan | None = None,
) -> MotionPlan:
    """The plan closest to covering ``distance`` in ``duration`` that the axis's drive
    really runs (its quantized speed and ramps), within the axis's limits and the drive's
    register ranges. ``shape`` gives the preferred ramp proportions. ``at_least``: the
    closest that takes no less than ``duration`` (a coarse drive sets the pace then).

    ``ceiling``: the most speed and ramps it may use (default: the axis's own).
    ``LimitViolation`` if no plan fits the drive at all. Fits are remembered per axis (a
    path's repeated segments, a group's re-plans ask the same again). The search gives
    the event loop a turn every ``_CANDIDATES_PER_TURN`` candidates (each a dry run
    through the drive's codecs): a stop goes out meanwhile.
    """
    d = abs(distance)
    own = ceiling or axis.plan()
    if d == 0:
        return own
    memo: dict[tuple[object, ...], MotionPlan] = axis.__dict__.setdefault("_fits", {})
    key = (d, duration, shape, at_least, own)
    found_before = memo.get(key)
    if found_before is not None:
        return found_before
    plan = await _fit(axis, d, duration, shape, at_least, own)
    if len(memo) >= _FIT_MEMO:
        memo.clear()
    memo[key] = plan
    return plan


async def _fit(axis: Axis, d: float, duration: float, shape: MotionPlan, at_least: bool,
               own: MotionPlan) -> MotionPlan:
    """``fit_plan``'s search (see there)."""
    axis.profile.quantize(axis.drive_params(own))  # a plan it takes: the fast rounding
    u, profile = axis.units, axis.profile
    found: list[tuple[float, float, MotionPlan]] = []
    seen: set[tuple[float, float, float]] = set()
    candidates: list[tuple[float, float, float]] = []

    def consider(v: float, a: float, b: float) -> None:
        candidates.append((v, a, b))

    def weigh(v: float, a: float, b: float) -> None:
        if not (v > 0 and a > 0 and b > 0) or not all(map(math.isfinite, (v, a, b))):
            return
        q = profile.quantize(axis.drive_params(MotionPlan(v, a, b)))
        key = (q.speed_rpm, q.accel_rps2, q.decel_rps2)
        if key in seen or min(key) <= 0:
            return
        seen.add(key)
        plan = MotionPlan(u.from_rpm(q.speed_rpm), u.from_rps2(q.accel_rps2),
                          u.from_rps2(q.decel_rps2))
        if (plan.speed > own.speed * 1.000001 or plan.accel > own.accel * 1.000001
                or plan.decel > own.decel * 1.000001):
            return
        error = plan.duration(d) - duration
        if at_least and error < -1e-9:
            return
        deviation = abs(plan.speed - shape.speed) / shape.speed
        found.append((abs(error), deviation, plan))

    for a0, b0 in ((shape.accel, shape.decel), (own.accel, own.decel)):
        ratio = b0 / a0
        v0 = _speed_for(d, duration, a0, b0) or min(own.speed, shape.speed)
        rpm0 = u.to_rpm(v0)
        for step in range(-3, 8 if at_least else 4):
            rpm = round(rpm0) - step if at_least else round(rpm0) + step
            if rpm <= 0:
                continue
            v = u.from_rpm(rpm)
            # Ramps (accel s, decel s * ratio) for exactly ``duration``: a triangle that
            # never reaches v, or a trapezoid that cruises at v.
            scales = [2 * d * (1 + ratio) / (ratio * duration * duration)]
            k = (duration - d / v) / v
            if k > 0:
                scales.append((1 + 1 / ratio) / (2 * k))
            for scale in scales:
                for j in range(-6, 7):  # ±2.4 %: the drive's neighbouring ramp steps
                    a = scale * (1 + 0.004 * j)
                    consider(v, a, a * ratio)
            consider(v, a0, b0)
        consider(v0, a0, b0)
    for i, candidate in enumerate(candidates):
        if i and i % _CANDIDATES_PER_TURN == 0:
            await anyio.lowlevel.checkpoint()
        weigh(*candidate)
    # The closest first (then the nearest to the preferred speed): the first the drive's
    # range checks take is the plan; most often that is the first, so few are checked.
    found.sort(key=lambda c: c[:2])
    first_error: LimitViolation | None = None
    for _, _, plan in found:
        try:
            profile.check_move(axis.drive_params(plan))
        except LimitViolation as exc:
            first_error = first_error or exc
            await anyio.lowlevel.checkpoint()  # each check is a dry run of the move
            continue
        return plan
    raise first_error or LimitViolation(
        f"axis {axis.name}: no speed and ramps the drive can run cover {d:g} in "
        f"{duration:.3f} s"
    )


@dataclass(frozen=True)
class GroupPlan:
    """A synchronised move of a group, planned and fitted, nothing sent yet."""

    targets: dict[str, float]
    starts: dict[str, float]
    distances: dict[str, float]
    total: float
    """Planned time from the first start to the common arrival, seconds."""
    plans: dict[str, MotionPlan]
    offsets: dict[str, float]
    delays: dict[str, float]


class StartGate:
    """Every axis prepares its move and waits here; once all are in, the gate holds the
    group's lines quiet and lets the axes send their start commands in the planned order.
    An axis too slow-stepped to stretch its move starts later instead, by ``delays``."""

    def __init__(
        self, order: Sequence[str], buses: Mapping[str, Bus], delays: Mapping[str, float]
    ) -> None:
        self.order = list(order)
        self.buses = buses
        self.delays = delays
        self._go = {n: anyio.Event() for n in self.order}
        self._left = len(self.order)
        self.all_in = anyio.Event()

    async def ready(self, name: str) -> None:
        """Called by each axis once its move is prepared; returns when it may start."""
        self._left -= 1
        if self._left <= 0:
            self.all_in.set()
        await self._go[name].wait()

    async def open(self) -> None:
        """Wait for every axis, hold the lines, release the axes in order."""
        await self.all_in.wait()
        opened = monotonic()
        now = [n for n in self.order if self.delays.get(n, 0.0) <= 0]
        await self._release(now)
        for name in sorted(set(self.order) - set(now), key=self.delays.__getitem__):
            at = opened + self.delays[name]
            await anyio.sleep(max(0.0, at - _HOLD_LEAD - monotonic()))
            await self._release([name], at)

    async def _release(self, names: Sequence[str], at: float = 0.0) -> None:
        async with AsyncExitStack() as stack:
            for bus in dict.fromkeys(self.buses[n] for n in names):
                await stack.enter_async_context(bus.hold())
            await anyio.sleep(max(0.0, at - monotonic()))
            for name in names:
                self._go[name].set()
            # The axes queue their start commands now, while the lines are held: they
            # leave first, back to back, in this order.
            await anyio.lowlevel.checkpoint()


def start_order(axes: Mapping[str, Axis], names: Iterable[str]) -> dict[str, float]:
    """Start order (the returned dict's order) and each axis's predicted delay from
    the moment the gate opens to its drive receiving the start command.

    On a serial line the start commands follow each other: an axis's delay is the
    wire time of the starts before it, with their replies and silences. The shortest
    transactions go first, so the last axis waits as little as possible.
    """
    by_bus: dict[int, list[Axis]] = {}
    for n in names:
        ax = axes[n]
        by_bus.setdefault(id(ax.profile.slave.bus), []).append(ax)
    offsets: dict[str, float] = {}
    for axes in by_bus.values():
        line_settings = axes[0].profile.slave.bus.line.settings
        if line_settings is None:  # Modbus TCP: the starts go out at once
            for i, ax in enumerate(axes):
                offsets[ax.name] = _NETWORK_DELAY * (i + 1)
            continue
        at = {ax.name: ax.profile.slave.settings or line_settings for ax in axes}
        axes.sort(key=lambda ax: timing(at[ax.name]).transaction_time(
            _START_FRAME, _START_FRAME, _TURNAROUND))
        t = timing(at[axes[0].name]).t35 / 2  # the silence after the last frame, on average
        previous: LineSettings | None = None
        for ax in axes:
            s = at[ax.name]
            if previous is not None:
                t += switch_silence(previous, s)
            tm = timing(s)
            offsets[ax.name] = t + tm.frame_time(_START_FRAME)
            t += tm.frame_time(_START_FRAME) * 2 + _TURNAROUND
            previous = s
    return {n: offsets[n] for n in sorted(offsets, key=offsets.__getitem__)}

def _shape(
    axes: Mapping[str, Axis],
    distances: Mapping[str, float],
    speed: float | None,
    accel: float | None,
    decel: float | None,
    duration: float | None,
) -> tuple[dict[str, MotionPlan], dict[str, MotionPlan] | None, float]:
    """Each axis's limits for ``synchronise``, the ceilings its fitted plan may reach
    (None: its own defaults) and the least duration, from a path ``speed``, ``accel``
    and ``decel`` (along the straight line, in the axes' common unit) or a
    ``duration``; neither: every axis at most at its defaults."""
    def given(name: str, value: float | None, unit: str) -> float | None:
        return None if value is None else checks.positive(name, value, unit=unit)

    speed = given("speed", speed, "units/s")
    accel = given("accel", accel, "units/s²")
    decel = given("decel", decel, "units/s²")
    duration = given("duration", duration, "s")
    own = {n: axes[n].plan() for n in distances}
    if duration is not None:
        if speed is not None or accel is not None or decel is not None:
            raise ArgumentError("give a group move a duration or a speed and ramps, "
                                "not both")
        limits = {n: MotionPlan(axes[n].config.max_speed or own[n].speed,
                                own[n].accel, own[n].decel) for n in distances}
        return limits, limits, duration
    if speed is None and accel is None and decel is None:
        return own, None, 0.0
    moving = {n: abs(d) for n, d in distances.items() if d != 0}
    units = {axes[n].config.unit for n in moving}
    if len(units) > 1:
        named = ", ".join(f"{n} ({axes[n].config.unit})" for n in moving)
        raise ArgumentError(f"a path speed needs the axes in one unit, not {named}: give "
                            f"a duration instead")
    length = math.sqrt(sum(d * d for d in moving.values()))
    if length == 0:
        return own, None, 0.0
    share = {n: d / length for n, d in moving.items()}
    # unset values: the most the slowest-limited axis allows along this line
    v = speed or min(own[n].speed / share[n] for n in moving)
    a = accel or min(own[n].accel / share[n] for n in moving)
    b = decel or min(own[n].decel / share[n] for n in moving)
    limits = dict(own)
    ceilings = dict(own)
    for n, r in share.items():
        axis = axes[n]
        plan = axis.plan(v * r, a * r, b * r)  # LimitViolation beyond max_speed
        mine = own[n]
        try:
            axis.check_drive(plan)
            floor = MotionPlan(0.0, 0.0, 0.0)
        except LimitViolation:
            # Below what the drive runs at least (ramps too gentle for it: the small
            # share of an axis that moves little) the fit takes ramps up to the axis's
            # own, as for a move without a speed; beyond what it runs at most is refused.
            axis.check_drive(MotionPlan(max(plan.speed, mine.speed),
                                        max(plan.accel, mine.accel),
                                        max(plan.decel, mine.decel)))
            floor = mine
        limits[n] = plan
        top = axis.config.max_speed or math.inf
        # a little room to suit the drive's steps, not more: the path's own values
        ceilings[n] = MotionPlan(min(top, plan.speed * 1.02),
                                 max(plan.accel * 1.02, floor.accel),
                                 max(plan.decel * 1.02, floor.decel))
    return limits, ceilings, 0.0

async def plan(
    axes: Mapping[str, Axis],
    targets: Mapping[str, float],
    starts: Mapping[str, float],
    *,
    speed: float | None = None,
    accel: float | None = None,
    decel: float | None = None,
    duration: float | None = None,
    offsets: dict[str, float] | None = None,
) -> GroupPlan:
    """Every axis's plan for a synchronised move from ``starts`` to ``targets``, fitted
    to its drive (nothing is sent): ``LimitViolation`` if one cannot make it. It gives
    the event loop a turn after each axis's fit, so nothing else waits on it (a stop
    of any axis goes out meanwhile)."""
    distances = {n: targets[n] - starts[n] for n in targets}
    limits, ceilings, least = _shape(axes, distances, speed, accel, decel, duration)
    natural, shapes = synchronise(distances, limits, least)
    if duration is not None and natural > duration * (1 + 1e-9):
        lead = max((n for n in distances if distances[n]),
                   key=lambda n: limits[n].duration(distances[n]))
        raise LimitViolation(
            f"the group cannot move in {duration:g} s: axis {lead} needs at least "
            f"{limits[lead].duration(distances[lead]):.3f} s for "
            f"{abs(distances[lead]):g} {axes[lead].config.unit} at its speed and "
            f"acceleration limits")
    if offsets is None:
        offsets = start_order(axes, targets)
    moving = [n for n in targets if distances[n] != 0]
    total = max(
        (limits[n].duration(distances[n]) + offsets[n] for n in moving), default=0.0
    )
    total = max(total, natural)
    plans = {n: limits[n] for n in targets}
    miss: dict[str, float] = {}

    def ceiling(n: str) -> MotionPlan | None:
        return None if ceilings is None else ceilings[n]

    for _ in range(8):  # every plan is checked against its drive before any axis moves
        for n in moving:
            plans[n] = await fit_plan(axes[n], distances[n], total - offsets[n], shapes[n],
                                ceiling=ceiling(n))
            await anyio.lowlevel.checkpoint()
        miss = {n: plans[n].duration(distances[n]) + offsets[n] - total for n in moving}
        late = [n for n in moving if miss[n] > _ARRIVAL_TOLERANCE]
        if late:  # its drive cannot run quite that fast: it sets the pace
            total += max(miss[n] for n in late)
            continue
        early = [n for n in moving if miss[n] < -_ARRIVAL_TOLERANCE]
        if not early:
            break
        # A drive too coarse-stepped to hit the duration: the next duration it can
        # run that is no shorter, if that costs little; else it starts later.
        n = min(early, key=miss.__getitem__)
        try:
            slower = await fit_plan(axes[n], distances[n], total - offsets[n], shapes[n],
                              at_least=True, ceiling=ceiling(n))
        except LimitViolation:
            break
        await anyio.lowlevel.checkpoint()
        longer = slower.duration(distances[n]) + offsets[n]
        if longer - total > max(_STRETCH_LIMIT, 0.1 * total):
            break
        total = max(total + 1e-4, longer)
    delays = {n: -miss[n] for n in moving if miss.get(n, 0.0) < -_ARRIVAL_TOLERANCE}
    return GroupPlan(dict(targets), dict(starts), distances, total, plans, offsets,
                      delays)

def start_gate(axes: Mapping[str, Axis], plan: GroupPlan) -> StartGate:
    """The gate that starts ``plan``'s axes back to back on their held lines."""
    buses = {n: axes[n].profile.slave.bus for n in plan.targets}
    return StartGate(list(plan.offsets), buses, plan.delays)
