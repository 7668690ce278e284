"""Real-time 1-D kinematics for simulated drives: trapezoidal moves, speed runs, stops.

Motion is a list of constant-acceleration segments planned when a command arrives and
evaluated lazily at any time ``t`` (no background task). Units are the caller's (the
simulated drives use pulses, pulses/s and pulses/s²).
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass

__all__ = ["Kinematics", "Segment"]


@dataclass(frozen=True, slots=True)
class Segment:
    """From ``t0`` for ``duration`` seconds: start at ``p0`` with ``v0``, accelerate at ``a``."""

    t0: float
    duration: float  # math.inf for the last segment of a speed run
    p0: float
    v0: float
    a: float

    def at(self, t: float) -> tuple[float, float]:
        dt = min(max(t - self.t0, 0.0), self.duration)
        return self.p0 + self.v0 * dt + 0.5 * self.a * dt * dt, self.v0 + self.a * dt

    @property
    def t1(self) -> float:
        return self.t0 + self.duration


def _end(seg: Segment) -> float:
    """Where ``seg`` ends: the next segment starts exactly there (no rounding gap at joins)."""
    return seg.at(seg.t1)[0]


_HISTORY = 100_000
"""Superseded segments a twin keeps for tests to look back at (its velocity over time)."""


class Kinematics:
    """Position and velocity of one simulated axis over time."""

    def __init__(self, position: float = 0.0) -> None:
        self.history: deque[Segment] = deque(maxlen=_HISTORY)
        """The motion so far: each plan's segments up to where the next plan took over."""
        self._plan: list[Segment] = []
        self._segments = [Segment(0.0, math.inf, position, 0.0, 0.0)]
        self.target: float | None = None

    @property
    def _segments(self) -> list[Segment]:
        return self._plan

    @_segments.setter
    def _segments(self, segments: list[Segment]) -> None:
        """A new plan from ``segments[0].t0``: what the old one did before that is kept."""
        t = segments[0].t0
        for seg in self._plan:
            if seg.t0 < t:
                self.history.append(Segment(seg.t0, min(seg.duration, t - seg.t0), seg.p0,
                                            seg.v0, seg.a))
        self._plan = segments

    def trace(self, t0: float, t1: float) -> list[Segment]:
        """The segments the axis ran between ``t0`` and ``t1`` (history, then the plan)."""
        return [s for s in (*self.history, *self._plan) if s.t1 > t0 and s.t0 < t1]

    # -- queries ---------------------------------------------------------------------------

    def state(self, t: float) -> tuple[float, float]:
        """(position, velocity) at time ``t``."""
        for seg in self._segments:
            if t < seg.t1:
                return seg.at(t)
        return self._segments[-1].at(t)

    def position(self, t: float) -> float:
        """Position at ``t``."""
        return self.state(t)[0]

    def velocity(self, t: float) -> float:
        """Velocity at ``t``."""
        return self.state(t)[1]

    def moving(self, t: float) -> bool:
        """True while the velocity is not zero or a planned change is still ahead."""
        last = self._segments[-1]
        if t < last.t0:
            return True
        return last.v0 != 0.0 or last.a != 0.0

    def cruising(self, t: float) -> bool:
        """True if at ``t`` the axis runs at the constant speed of a speed run's end."""
        last = self._segments[-1]
        return t >= last.t0 and last.a == 0.0 and last.v0 != 0.0

    def steady(self, t: float) -> bool:
        """True if at ``t`` the axis runs at a constant, non-zero speed (a move's cruise,
        a speed run at its speed)."""
        for seg in self._segments:
            if t < seg.t1:
                return seg.a == 0.0 and seg.v0 != 0.0
        last = self._segments[-1]
        return last.a == 0.0 and last.v0 != 0.0

    def end_time(self) -> float:
        """When the planned motion comes to rest (inf for a speed run)."""
        last = self._segments[-1]
        return last.t0 if last.v0 == 0.0 and last.a == 0.0 else math.inf

    def crossing(self, p: float, t_from: float, t_to: float) -> float | None:
        """First time in [t_from, t_to] at which the position passes ``p``, else None."""
        for seg in self._segments:
            lo, hi = max(seg.t0, t_from), min(seg.t1, t_to)
            if lo > hi:
                continue
            (p_lo, _), (p_hi, _) = seg.at(lo), seg.at(hi)
            if abs(p_lo - p) < 1e-6:
                return lo  # sitting on it (a previous crossing may leave 1e-12 of float error)
            if (p_lo - p) * (p_hi - p) > 0:
                continue
            # Solve p0 + v0*dt + a/2*dt^2 = p on this segment.
            a, v0, c = 0.5 * seg.a, seg.v0, seg.p0 - p
            if abs(a) < 1e-12:
                dt = -c / v0 if v0 else 0.0
                return seg.t0 + dt
            disc = max(v0 * v0 - 4 * a * c, 0.0)
            roots = sorted(((-v0 - math.sqrt(disc)) / (2 * a), (-v0 + math.sqrt(disc)) / (2 * a)))
            for dt in roots:
                if lo - 1e-12 <= seg.t0 + dt <= hi + 1e-12:
                    return seg.t0 + dt
            return hi
        return None

    def entering(self, p: float, direction: int, t_from: float, t_to: float) -> float | None:
        """First time in [t_from, t_to] at which the axis passes ``p`` moving in
        ``direction`` (+1/-1): a switch at ``p`` met on the way in, not on the way out
        (the first few crossings are looked at), else None."""
        t0 = t_from
        for _ in range(4):
            tc = self.crossing(p, t0, t_to)
            if tc is None:
                return None
            if self.velocity(tc) * direction > 0:
                return tc
            t0 = tc + 1e-6
        return None

    # -- commands ------------------------------------------------------------------------------

    def _start(self, t: float) -> tuple[float, float]:
        p, v = self.state(t)
        return p, v

    def hold(self, t: float, position: float | None = None) -> None:
        """Stand still from ``t`` (at ``position`` if given: zeroing, homing offsets)."""
        p, _ = self._start(t)
        self._segments = [Segment(t, math.inf, p if position is None else position, 0.0, 0.0)]
        self.target = None

    def set_position(self, t: float, position: float) -> None:
        """Redefine the present position as ``position`` without changing the motion."""
        p, _ = self.state(t)
        shift = position - p
        self._segments = [
            Segment(s.t0, s.duration, s.p0 + shift, s.v0, s.a) for s in self._segments
        ]
        if self.target is not None:
            self.target += shift

    def stop(self, t: float, decel: float | None) -> None:
        """Decelerate to rest at ``decel`` (None or inf: stop at once)."""
        p, v = self._start(t)
        self.target = None
        if v == 0.0 or decel is None or math.isinf(decel) or decel <= 0:
            self._segments = [Segment(t, math.inf, p, 0.0, 0.0)]
            return
        a = -math.copysign(decel, v)
        dur = abs(v) / decel
        ramp = Segment(t, dur, p, v, a)
        self._segments = [ramp, Segment(t + dur, math.inf, _end(ramp), 0.0, 0.0)]

    def run(self, t: float, speed: float, accel: float, decel: float) -> None:
        """Ramp to ``speed`` (signed) and keep running; a new call changes the speed."""
        p, v = self._start(t)
        self.target = None
        segs: list[Segment] = []
        if v != 0.0 and (v > 0) != (speed > 0) and speed != 0.0:
            # Reverse: brake to zero first.
            dur = abs(v) / decel
            a = -math.copysign(decel, v)
            segs.append(Segment(t, dur, p, v, a))
            p, v, t = _end(segs[-1]), 0.0, t + dur
        rate = accel if abs(speed) > abs(v) else decel
        dur = abs(speed - v) / rate if rate > 0 else 0.0
        a = math.copysign(rate, speed - v) if dur > 0 else 0.0
        if dur > 0:
            segs.append(Segment(t, dur, p, v, a))
            p, v, t = _end(segs[-1]), speed, t + dur
        segs.append(Segment(t, math.inf, p, speed, 0.0))
        self._segments = segs

    def move_to(self, t: float, target: float, speed: float, accel: float, decel: float) -> None:
        """Trapezoidal move to ``target`` at up to ``speed`` (accel/decel > 0)."""
        if speed <= 0 or accel <= 0 or decel <= 0:
            raise ValueError("speed, accel and decel must be > 0")
        p, v = self._start(t)
        segs: list[Segment] = []
        dist = target - p
        direction = 1.0 if dist >= 0 else -1.0
        u = v * direction  # speed along the direction of the target
        if u < 0 or (u * u) / (2 * decel) > abs(dist) + 1e-9:
            # Moving away, or cannot stop in time: brake to rest, then plan from rest.
            dur = abs(v) / decel
            a = -math.copysign(decel, v) if v else 0.0
            if dur > 0:
                segs.append(Segment(t, dur, p, v, a))
                p = _end(segs[-1])
            t = t + dur
            v = 0.0
            dist = target - p
            direction = 1.0 if dist >= 0 else -1.0
            u = 0.0
        d_abs = abs(dist)
        vp = math.sqrt((2 * accel * decel * d_abs + decel * u * u) / (accel + decel))
        # Faster than the new speed already: down to it (it always fits: braking from u
        # through the new speed to rest takes the same distance as braking from u).
        vp = min(vp, speed) if u <= speed else speed
        up_rate = accel if vp >= u else decel
        t_up = abs(vp - u) / up_rate
        d_up = (vp * vp - u * u) / (2 * (up_rate if vp >= u else -up_rate))
        t_down = vp / decel
        d_down = vp * vp / (2 * decel)
        d_cruise = max(d_abs - d_up - d_down, 0.0)
        t_cruise = d_cruise / vp if vp > 0 else 0.0
        s = direction
        if t_up > 0:
            segs.append(Segment(t, t_up, p, s * u, s * (up_rate if vp >= u else -up_rate)))
            p, t = _end(segs[-1]), t + t_up
        if t_cruise > 0:
            segs.append(Segment(t, t_cruise, p, s * vp, 0.0))
            p, t = _end(segs[-1]), t + t_cruise
        if t_down > 0:
            segs.append(Segment(t, t_down, p, s * vp, -s * decel))
            t = t + t_down
        segs.append(Segment(t, math.inf, target, 0.0, 0.0))
        self._segments = segs
        self.target = target
