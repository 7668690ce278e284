"""Profile position (set-points and their handshake) and profile velocity, and the limit
switches that block or stop them.
"""

from __future__ import annotations

import math

from drivebus.drives.cia402 import Controlword, Statusword
from drivebus.sim.cia402_device.base import DeviceBase
from drivebus.sim.cia402_device.state import _AT_ONCE, _Edge, _PointSet


class Profiles(DeviceBase):
    """Profile position, profile velocity and the limit switches."""

    def _new_set_point(self, word: int, now: float) -> None:
        prof = self._profile
        busy = self.kin.moving(now) and prof.target is not None
        immediate = bool(word & Controlword.CHANGE_SET_IMMEDIATELY)
        if self._into_limit(now):  # the limit stop goes on; the set-point waits for it
            busy, immediate = True, False
        if busy and not immediate and prof.pending is not None:
            return  # the one waiting slot is taken: no acknowledge
        target = float(self.values["target_position"])
        if word & Controlword.RELATIVE:
            base = (prof.pending.target if prof.pending is not None and not immediate
                    else prof.target)
            if base is None or (prof.ended_short and prof.pending is None):
                base = self.kin.position(now)
            target += base
        point = _PointSet(target, self._speed("profile_velocity"),
                          self.values["profile_acceleration"] * self.setup.acceleration_unit,
                          self.values["profile_deceleration"] * self.setup.acceleration_unit)
        prof.acknowledge = True
        if busy and not immediate:
            prof.pending = point
        else:
            prof.pending = None
            self._start_point(point, now)

    def _continue(self, now: float) -> None:
        """Halt cleared in profile position: the interrupted positioning goes on to its
        target, with the profile's present velocity and ramps (CiA 402-2, controlword bit
        8: "0: positioning shall be executed or continued")."""
        target, self._profile.halted = self._profile.halted, None
        assert target is not None
        self._start_point(_PointSet(
            target, self._speed("profile_velocity"),
            self.values["profile_acceleration"] * self.setup.acceleration_unit,
            self.values["profile_deceleration"] * self.setup.acceleration_unit), now)

    def _start_point(self, point: _PointSet, now: float) -> None:
        prof = self._profile
        prof.target, prof.ended_short, prof.stalled = point.target, False, False
        prof.halted = None
        p = self.kin.position(now)
        if min(point.velocity, point.acceleration, point.deceleration) <= 0:
            prof.stalled = True
            self._stop(now, point.deceleration or None)
            return
        if self._blocked(point.target - p, now):
            prof.ended_short = True
            self.kin.stop(now, self._rate("quick_stop_deceleration"))
            return
        self.kin.move_to(now, point.target, point.velocity, point.acceleration,
                         point.deceleration)
        self._watch_from = now

    def _pp_bits(self, now: float, moving: bool) -> int:
        prof = self._profile
        word = Statusword.SET_POINT_ACKNOWLEDGE if prof.acknowledge else 0
        if moving or prof.pending is not None or prof.stalled:
            return word
        at_target = prof.target is None or abs(self.kin.position(now) - prof.target) < 0.5
        if at_target or prof.ended_short:
            word |= Statusword.TARGET_REACHED
        return word

    def _velocity(self, now: float) -> None:
        """Run at the target velocity (a limit switch in the way: stand)."""
        speed = self._speed("target_velocity")
        if self._into_limit(now):
            self._pv_deferred = True  # the limit stop goes on; the velocity counts after it
            return
        if self._blocked(speed, now):
            self.kin.stop(now, self._rate("quick_stop_deceleration"))
            self._watch_from = None
            return
        accel = self._rate("profile_acceleration") or _AT_ONCE
        decel = self._rate("profile_deceleration") or _AT_ONCE
        if speed == 0.0:
            self._stop(now, decel)
        else:
            self.kin.run(now, speed, accel, decel)
        self._watch_from = now

    def _pv_bits(self, now: float, moving: bool) -> int:
        v = self.kin.velocity(now)
        word = Statusword.SPEED_ZERO if abs(v) < 1e-9 else 0
        if self._halted or self._watch_from is None:  # halted, or stopped by a limit switch
            return word | (0 if moving else Statusword.TARGET_REACHED)
        if abs(v - self._speed("target_velocity")) < 1e-6 and not self._ramping(now):
            word |= Statusword.TARGET_REACHED
        return word

    def _ramping(self, now: float) -> bool:
        """True while the velocity is still changing."""
        last = self.kin.end_time()
        if not math.isinf(last):
            return now < last
        return abs(self.kin.velocity(now) - self.kin.velocity(now + 1e-3)) > 1e-9

    def _blocked(self, direction: float, now: float) -> bool:
        """True if a limit switch in ``direction`` is active: the drive will not go on."""
        _, neg, pos = self._switches(now)
        return (direction > 0 and pos) or (direction < 0 and neg)

    def _into_limit(self, now: float) -> bool:
        """True while the axis still moves into an active limit switch (stopping)."""
        v = self.kin.velocity(now)
        return v != 0.0 and self._blocked(v, now)

    def _stop(self, now: float, ramp: float | None) -> None:
        """Stop on ``ramp`` (None: at once), never slower than the quick stop ramp while
        the axis moves into an active limit switch."""
        if ramp is not None and self._into_limit(now):
            quick = self._rate("quick_stop_deceleration")
            ramp = None if quick is None else max(ramp, quick)
        self.kin.stop(now, ramp)

    def _limit_edges(self) -> list[_Edge]:
        s, edges = self.setup, []
        if s.limit_negative is not None:
            edges.append(_Edge(s.limit_negative, -1, "negative limit"))
        if s.limit_positive is not None:
            edges.append(_Edge(s.limit_positive, +1, "positive limit"))
        return edges

    def _crossing(self, edge: _Edge, t_from: float, now: float,
                  direction: int | None = None) -> float | None:
        """When the axis first crosses ``edge`` in [t_from, now] (moving ``direction`` if
        given, +1 or -1), in the physical frame."""
        p = edge.position + self._shift
        t0 = t_from
        for _ in range(8):
            tc = self.kin.crossing(p, t0, now)
            if tc is None:
                return None
            v = self.kin.velocity(tc)
            if v != 0.0 and (direction is None or v * direction > 0):
                return tc
            t0 = tc + 1e-6
            if t0 > now:
                return None
        return None

    def _limit_hit(self, now: float) -> float | None:
        """When a PP or PV motion ran into a limit switch since it started (or None)."""
        if self._watch_from is None:
            return None
        hits = [tc for edge in self._limit_edges()
                if (tc := self._crossing(edge, self._watch_from, now, edge.active_side))
                is not None]
        return min(hits) if hits else None

    def _stop_at_limit(self, tc: float) -> None:
        self.kin.stop(tc, self._rate("quick_stop_deceleration"))
        self._drop_set_points()
