"""Trajectory: where a planned motion is at any moment (user units, seconds).

Motion programs decide *when* to send a command from what the drive will do: the moment a
move arrives (a buffered move starts then), the moment a move begins to brake (a blend
must reach the drive before it), how fast the axis passes a blended point, how far a
group's path strays from the straight line. They all ask a ``Trajectory``: a sequence of
constant-acceleration phases, the trapezoid a drive runs for a point-to-point move, and
what a drive that takes a new target on the fly does from its present speed.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from drivebus.motion.envelope import MotionPlan

__all__ = ["Phase", "Trajectory"]


@dataclass(frozen=True, slots=True)
class Phase:
    """From ``t0`` for ``duration`` s: from ``p0`` at velocity ``v0``, accelerating at ``a``."""

    t0: float
    duration: float
    p0: float
    v0: float
    a: float

    @property
    def t1(self) -> float:
        """When the phase ends."""
        return self.t0 + self.duration

    def at(self, t: float) -> tuple[float, float]:
        """(position, velocity) at ``t`` (clamped to the phase)."""
        dt = min(max(t - self.t0, 0.0), self.duration)
        return self.p0 + self.v0 * dt + 0.5 * self.a * dt * dt, self.v0 + self.a * dt


@dataclass(frozen=True)
class Trajectory:
    """A planned motion: its phases in time order, at rest at ``target`` after the last."""

    phases: tuple[Phase, ...]
    target: float

    @property
    def start(self) -> float:
        """When it begins."""
        return self.phases[0].t0

    @property
    def end(self) -> float:
        """When it comes to rest at ``target``."""
        return self.phases[-1].t1

    def state(self, t: float) -> tuple[float, float]:
        """(position, velocity) at ``t``: before the start where it begins, after the end
        at rest on the target."""
        if t >= self.end:
            return self.target, 0.0
        for phase in self.phases:
            if t < phase.t1:
                return phase.at(t)
        return self.target, 0.0  # pragma: no cover - t < end is inside a phase

    def position(self, t: float) -> float:
        """Where it is at ``t``."""
        return self.state(t)[0]

    def braking_starts(self) -> float:
        """When its last deceleration (towards rest on the target) begins."""
        last = self.phases[-1]
        return last.t0 if last.v0 * last.a < 0 else last.t1

    def can_brake_by(self, t: float, decel: float, *, lead: float,
                     margin: float = 1.25) -> bool:
        """Whether a ramp of ``decel`` given on the fly at ``t`` still brings it to rest on
        its target: from where it is ``lead`` seconds later at its speed (the new ramp's
        frames on their way), the braking distance with ``margin`` fits before the target."""
        pos, vel = self.state(t)
        room = abs(self.target - pos) - abs(vel) * lead
        return room >= margin * vel * vel / (2 * decel)

    def times(self, samples: int = 64) -> list[float]:
        """Moments to look at it: every phase boundary and ``samples`` in between."""
        out = {p.t0 for p in self.phases} | {self.end}
        span = self.end - self.start
        out |= {self.start + span * i / samples for i in range(samples + 1)}
        return sorted(out)

    @classmethod
    def point_to_point(
        cls,
        start: float,
        target: float,
        plan: MotionPlan,
        *,
        t0: float = 0.0,
        v0: float = 0.0,
    ) -> Trajectory:
        """A move to ``target`` from ``start`` at velocity ``v0`` (0: at rest), at most
        ``plan.speed``, ramping at ``plan.accel`` and ``plan.decel``: a trapezoid, or a
        triangle if it is short. Moving the wrong way, or too fast to stop in time, it
        brakes to rest first and plans from there (as a drive that takes a new target
        on the fly does)."""
        phases: list[Phase] = []
        p, v, t = start, v0, t0
        distance = target - p
        sign = 1.0 if distance >= 0 else -1.0
        u = v * sign  # speed towards the target
        if u < 0 or u * u / (2 * plan.decel) > abs(distance) + 1e-12:
            if v != 0:
                brake = abs(v) / plan.decel
                phases.append(Phase(t, brake, p, v, -math.copysign(plan.decel, v)))
                p, t = phases[-1].at(phases[-1].t1)[0], t + brake
            v, u = 0.0, 0.0
            distance = target - p
            sign = 1.0 if distance >= 0 else -1.0
        d = abs(distance)
        if d == 0 and u == 0:
            return cls((Phase(t, 0.0, p, 0.0, 0.0),) if not phases else tuple(phases), target)
        a, b = plan.accel, plan.decel
        # The highest speed reachable: accelerate from u, then brake to rest within d.
        peak = math.sqrt((2 * a * b * d + b * u * u) / (a + b))
        # Faster than the plan already: down to its speed first (braking from u through
        # it to rest takes the same distance as braking from u, which fits).
        top = min(peak, plan.speed) if u <= plan.speed else plan.speed
        rate = a if top >= u else b
        t_up = abs(top - u) / rate
        d_up = abs(top * top - u * u) / (2 * rate)
        d_down = top * top / (2 * b)
        cruise = max(d - d_up - d_down, 0.0)
        for duration, speed, acc in (
            (t_up, u, rate if top >= u else -rate),
            (cruise / top if top > 0 else 0.0, top, 0.0),
            (top / b, top, -b),
        ):
            if duration > 0:
                phases.append(Phase(t, duration, p, sign * speed, sign * acc))
                p, t = phases[-1].at(phases[-1].t1)[0], t + duration
        return cls(tuple(phases), target)

    def retargeted(self, at: float, target: float, plan: MotionPlan) -> Trajectory:
        """This motion until ``at``, then a new target taken on the fly at ``plan``."""
        kept = tuple(
            Phase(p.t0, min(p.duration, at - p.t0), p.p0, p.v0, p.a)
            for p in self.phases if p.t0 < at
        )
        p, v = self.state(at)
        rest = Trajectory.point_to_point(p, target, plan, t0=at, v0=v)
        return Trajectory(kept + rest.phases, target)

    def speed_at(self, position: float) -> float | None:
        """|velocity| when it first passes ``position`` (None: it never does)."""
        for phase in self.phases:
            (p0, _), (p1, _) = phase.at(phase.t0), phase.at(phase.t1)
            if min(p0, p1) - 1e-9 <= position <= max(p0, p1) + 1e-9:
                lo, hi = phase.t0, phase.t1
                for _ in range(60):  # positions are monotonic within a phase
                    mid = (lo + hi) / 2
                    if (phase.at(mid)[0] - position) * (p1 - p0) < 0:
                        lo = mid
                    else:
                        hi = mid
                return abs(phase.at(hi)[1])
        return None
