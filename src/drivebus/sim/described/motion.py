"""A described twin's motion: moves and speed runs on its kinematics, limit switches
that block or stop them, and the twin's time brought up to now (the homing legs,
tables and limit stops in the order they happen).
"""

from __future__ import annotations

import math
from typing import Any

from drivebus.drives.description import Trigger
from drivebus.sim.described.base import TwinBase, _finite_pos, _rate, _usable
from drivebus.sim.described.state import _Handler


class Motion(TwinBase):
    """Moves, speed runs, limit stops, and advancing the twin's events to now."""

    def _blocked(self, direction: float, now: float) -> bool:
        """True if a limit input in ``direction`` is active (the drive will not go on)."""
        if not self.description.twin.limits.block_start:
            return False
        _, neg, pos = self.switch_states(now)
        return (direction > 0 and pos and self._wired("limit_positive")) or (
            direction < 0 and neg and self._wired("limit_negative"))

    def _move(self, trig: Trigger, value: Any, now: float) -> None:
        ppr = self.pulses_per_rev
        speed = self._param(trig, "speed", now, value)
        accel = self._param(trig, "accel", now, value)
        decel = self._param(trig, "decel", now, value)
        if not _usable(speed, accel, decel):
            return
        p = self._wrap(now)
        if trig.do == "move_absolute":
            target = float(self._param(trig, "target", now, value))
        else:
            target = round(p) + float(self._param(trig, "distance", now, value))
        if self._blocked(target - p, now):
            return
        a, dc = float(accel) * ppr, float(decel) * ppr
        self.kin.move_to(now, target, self._pps(abs(float(speed))), a, dc)
        self._started(trig, "position", now, dc)

    def _run(self, trig: Trigger, value: Any, now: float) -> None:
        ppr = self.pulses_per_rev
        speed = float(self._param(trig, "speed", now, value) or 0.0)
        accel = self._param(trig, "accel", now, value)
        decel = self._param(trig, "decel", now, value)
        if self._blocked(speed, now):
            return
        self._wrap(now)
        a = float(accel) * ppr if _finite_pos(accel) else math.inf
        dc = float(decel) * ppr if _finite_pos(decel) else math.inf
        if speed == 0:
            self.kin.stop(now, dc)
        else:
            self.kin.run(now, self._pps(speed), a, dc)
        self._run_rates = (a, dc)
        self._started(trig, "speed", now, dc)

    def _set_speed(self, trig: Trigger, value: Any, now: float) -> None:
        if self.motion != "speed" or not self.kin.moving(now) or self.stopping:
            return  # a new speed does not restart a motor that is being stopped
        speed = float(self._param(trig, "speed", now, value) or 0.0)
        v = self.kin.velocity(now)
        signed = math.copysign(abs(speed), v) if v else speed
        a, dc = self._run_rates
        self.kin.run(now, self._pps(signed), a, dc)

    def _started(self, trig: Trigger, kind: str, now: float, decel: float) -> None:
        self.motion = trig.motion or kind
        self._watch_from = now
        self._motion_decel = decel
        self._homing = None
        self._ref = None
        self._table = None
        self.stopping = None
        self.reached = False
        self._completes = kind == "position"
        self._processed_until = max(self._processed_until, now)
        v = self.kin.velocity(now + 1e-3)
        if v:
            self._last_dir = -1 if v < 0 else 1

    def _limit_rate(self, t: float) -> float | None:
        lim = self.description.twin.limits
        mode = self._eval(lim.stop, t)
        if mode == "immediate":
            return None
        if lim.decel is not None:
            return _rate(self._eval(lim.decel, t), self.pulses_per_rev)
        return self._motion_decel

    def _limit_hit(self, now: float) -> float | None:
        hits = []
        for boundary, direction in ((self._boundary("limit_positive"), 1),
                                    (self._boundary("limit_negative"), -1)):
            if boundary is None:
                continue
            tc = self.kin.entering(boundary, direction, self._watch_from, now)
            if tc is not None:
                hits.append(tc)
        return min(hits) if hits else None

    def _wired_limit_stop(self, t: float) -> None:
        self.kin.stop(t, self._limit_rate(t))
        self.stopping = "limit"
        self._completes = False

    def _wired_event(self, t0: float, t1: float) -> tuple[float, _Handler] | None:
        """The next reaction in [t0, t1] of a twin with wired inputs."""
        if t1 < t0:
            return None
        end = self.kin.end_time()
        tr = self._table
        if tr is not None:
            if tr.phase == "wait":
                return (max(tr.until, t0), self._table_waited) if tr.until <= t1 else None
            return _first((max(end, t0) if end <= t1 else None, self._table_moved),
                          *((self._signal_edge(lim, True, t0, t1), self._table_limit)
                            for lim in ("limit_positive", "limit_negative")))
        h = self._ref
        if h is not None:
            if h.phase == "search":
                return _first((self._signal_edge(h.reference, True, t0, t1), self._ref_found),
                              *self._ref_limits(t0, t1,
                                                reverse=h.may_reverse and not h.reversed))
            if h.phase == "backoff":
                return _first((self._signal_edge(h.reference, False, t0, t1), self._ref_left),
                              *self._ref_limits(t0, t1))
            if h.phase == "pass":
                return _first((self._signal_edge(h.reference, False, t0, t1),
                               self._ref_passed), *self._ref_limits(t0, t1))
            if h.phase == "creep":
                return _first((self._signal_edge(h.reference, True, t0, t1), self._ref_origin),
                              *self._ref_limits(t0, t1))
            if h.phase == "offset":
                return _first((end if end <= t1 else None, self._ref_ramp_end),
                              *self._ref_limits(t0, t1, offset=True))
            if h.phase == "press":
                return _first((self._press_end(t0, t1), self._stall),
                              *self._ref_limits(t0, t1))
            if h.phase == "stall":
                return (h.until, self._ref_origin) if h.until <= t1 else None
            return (end, self._ref_ramp_end) if end <= t1 else None
        if self._homing is None and self.motion in ("position", "speed") and \
                self.kin.moving(t0):
            return _first(*((self._signal_edge(lim, True, t0, t1), self._wired_limit_stop)
                            for lim in ("limit_positive", "limit_negative")))
        return None

    def _advance_wired(self, now: float) -> None:
        for _ in range(64):
            t_from = max(self._processed_until, self._last_event + 1e-6)
            event = self._wired_event(t_from, now)
            if event is None:
                break
            t, handler = event
            self._last_event = t
            handler(t)
        self._processed_until = max(self._processed_until, now)

    def advance(self, now: float) -> None:
        """Bring homing legs, tables and limit stops up to ``now`` (state is computed
        lazily), then set the ``ends`` registers of a motion that is over."""
        self._advance(now)
        if self._ends is not None:
            self._settle(now)

    def _advance(self, now: float) -> None:
        twin = self.description.twin
        if (twin.wiring or twin.direct or self._ref is not None or
                self._table is not None) and self._homing is None:
            self._advance_wired(now)
            return
        if self._homing is not None:
            self._advance_homing(now)
            return
        if self.motion in ("position", "speed") and self.kin.moving(now):
            tc = self._limit_hit(now)
            if tc is not None:
                self.kin.stop(tc, self._limit_rate(tc))
                self.stopping = "limit"
                self._watch_from = now


def _first(*candidates: tuple[float | None, _Handler]) -> tuple[float, _Handler] | None:
    """The earliest of the events that happen (time not None)."""
    found = [(t, h) for t, h in candidates if t is not None]
    return min(found, key=lambda c: c[0]) if found else None
