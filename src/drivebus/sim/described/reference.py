"""A described twin's homing on a reference input's edge (``behaviour =
"reference_edge"``), into a hard stop (``"hard_stop"``) and to an offset
(``"move_to_offset"``), as ``[twin.homing]`` says: search, brake, back off, creep,
the origin and its offset.
"""

from __future__ import annotations

import math
from typing import Any

from drivebus.drives.description import HomingMethod as MethodDef
from drivebus.drives.expr import ExprError
from drivebus.sim.described.base import TwinBase, _finite_pos
from drivebus.sim.described.state import _Handler, _RefHoming


class ReferenceHoming(TwinBase):
    """Reference-edge, hard-stop and offset homing."""

    def _ref_home(self, method: MethodDef, speed: float, creep: float, accel: Any,
                  offset: float, now: float) -> None:
        """Search at ``speed`` in the method's direction until its reference input turns
        active, brake, back off (``[twin.homing]``: at ``speed`` or the creep speed) until
        it turns inactive, brake, creep back until it turns active: that edge is the
        origin (backing off with ``backoff_stop = "at_once"``, the edge it leaves is the
        origin). A limit switch ahead in the search reverses it once (where
        ``reverse_at_limit`` holds; else the homing fails there); any other stops the
        motor (as ``[twin] limits`` say) and the homing fails. Started on the reference,
        the twin backs off first."""
        ppr = self.pulses_per_rev
        assert method.reference is not None and method.direction is not None
        rate = float(accel) * ppr if _finite_pos(accel) else math.inf
        hd = self.description.twin.homing
        h = _RefHoming(method.reference, "search", float(method.direction),
                       self._pps(speed), self._pps(creep), rate, offset,
                       may_reverse=bool(self._eval(hd.reverse_at_limit, now)),
                       offset_mode=self._offset_mode(now))
        self._begin_ref(h, now)
        p = self._phys(now)
        if self._signal_at(h.reference, p):
            h.phase = "brake1"
            self._ref_ramp_end(now)
            return
        ahead = "limit_positive" if h.direction > 0 else "limit_negative"
        if ahead != h.reference and self._signal_at(ahead, p):
            if h.may_reverse:
                self._ref_reverse(now)  # on a limit already: the turning reverses
            else:
                self._ref_fail(now)
            return
        self._ref_run(now, h.direction * h.speed)

    def _offset_mode(self, now: float) -> str:
        """What a homing's offset does (``[twin.homing] offset``, else ``home_offset``)."""
        t = self.description.twin
        if t.homing.offset is None:
            return t.home_offset
        mode = self._eval(t.homing.offset, now)
        if mode not in ("origin", "move", "travel"):
            raise ExprError(f"twin.homing.offset {t.homing.offset.source!r} gave {mode!r}, "
                            "not 'origin', 'move' or 'travel'")
        return str(mode)

    def _begin_ref(self, h: _RefHoming, now: float) -> None:
        """Homing ``h`` runs from ``now`` (its legs are followed as the twin advances)."""
        self._ref = h
        self._homing = None
        self._motion_decel = h.rate
        self.reached = False
        self._completes = False
        self._processed_until = max(self._processed_until, now)

    def _ref_run(self, t: float, pps: float) -> None:
        h = self._ref
        assert h is not None
        self.kin.run(t, pps, h.rate, h.rate)
        self._last_dir = 1 if pps > 0 else -1

    def _ref_ramp_end(self, t: float) -> None:
        h = self._ref
        assert h is not None
        if h.phase == "brake1":
            h.phase = "backoff"
            back = h.creep if self.description.twin.homing.backoff == "creep" else h.speed
            self._ref_run(t, -h.direction * back)
        elif h.phase == "brake2":
            h.phase = "creep"
            self._ref_run(t, h.direction * h.creep)
        else:
            if h.phase == "offset" and h.final is not None:
                self._set_counter(t, h.final)  # "travel": the point reached is 0
            self._ref_done()

    def _ref_done(self) -> None:
        self._ref = None
        self.homed = True
        self.reached = True
        self.stalled = False

    def _stop_home(self, method: MethodDef, speed: float, creep: float, accel: Any,
                   offset: float, now: float) -> None:
        """``behaviour = "hard_stop"``: creep in the method's direction into the end stop
        (``hard_stop_positive``/``_negative``), stall there for ``[twin] stall_time``:
        that point is the origin (``home_offset`` as for an edge). A limit switch met
        first stops the motor and fails the homing; with neither it creeps on."""
        assert method.direction is not None
        rate = float(accel) * self.pulses_per_rev if _finite_pos(accel) else math.inf
        d = float(method.direction)
        stop = self.hard_stop_positive if d > 0 else self.hard_stop_negative
        h = _RefHoming("", "press", d, self._pps(speed), self._pps(creep), rate, offset,
                       offset_mode=self._offset_mode(now))
        h.stop = None if stop is None else stop + self._shift
        self._begin_ref(h, now)
        if h.stop is not None and (h.stop - self.kin.position(now)) * d <= 0:
            self._stall(now)  # on the end stop already
            return
        self._ref_run(now, d * h.creep)

    def _stall(self, t: float) -> None:
        h = self._ref
        assert h is not None
        self.kin.hold(t, h.stop)
        self.stalled = True
        h.phase = "stall"
        h.until = t + float(self._eval(self.description.twin.stall_time, t) or 0.0)

    def _press_end(self, t0: float, t1: float) -> float | None:
        """When the motor reaches the end stop ahead in [t0, t1] (None: not yet)."""
        h = self._ref
        assert h is not None
        return None if h.stop is None else self.kin.crossing(h.stop, t0, t1)

    def _ref_found(self, t: float) -> None:
        h = self._ref
        assert h is not None
        self.kin.stop(t, h.rate)
        h.phase = "brake1" if h.phase == "search" else "brake2"

    def _ref_reverse(self, t: float) -> None:
        """The search met the limit switch ahead: search the other way (``[twin.homing]
        after_reversal = "other_edge"``), or pass back through the reference to creep to
        the edge the search looked for (``"same_edge"``)."""
        h = self._ref
        assert h is not None
        h.reversed = True
        if self.description.twin.homing.after_reversal == "same_edge":
            h.phase = "pass"
            self._ref_run(t, -h.direction * h.speed)
            return
        h.direction = -h.direction
        self._ref_run(t, h.direction * h.speed)

    def _ref_passed(self, t: float) -> None:
        """Back through the reference after a reversal: brake, then creep back onto it."""
        h = self._ref
        assert h is not None
        self.kin.stop(t, h.rate)
        h.phase = "brake2"

    def _ref_left(self, t: float) -> None:
        """The back-off left the reference: brake and creep back, or (``backoff_stop =
        "at_once"``) stop at once on the edge, the origin."""
        if self.description.twin.homing.backoff_stop == "at_once":
            self._ref_origin(t)
        else:
            self._ref_found(t)

    def _ref_fail(self, t: float) -> None:
        """A limit switch met while homing (not the search's first): stop as ``[twin]
        limits`` say; the homing fails (reversing again would run between the limits)."""
        h = self._ref
        rate = None if self._eval(self.description.twin.limits.stop, t) == "immediate" \
            else (h.rate if h is not None else None)
        self.kin.stop(t, rate)
        self._ref = None
        self.stalled = False
        self.homing_failed = True

    def _ref_origin(self, t: float) -> None:
        """The origin edge: with ``home_offset = "move"`` the counter is 0 there and the
        compensation move of the offset follows at the creep speed; else the edge takes the
        offset as its position."""
        h = self._ref
        assert h is not None
        self.stalled = False
        if h.reference:
            self.kin.hold(t, self._on_edge(h.reference, self.kin.position(t)))
        mode = h.offset_mode
        if mode == "origin":
            self.kin.stop(t, h.rate)
            self._set_counter(t, h.offset)
            self._ref_done()
            return
        offset = h.offset
        if mode == "move" or not offset:
            self._set_counter(t, 0)
        if not offset:
            self._ref_done()
            return
        towards = "limit_positive" if offset > 0 else "limit_negative"
        if self._signal_at(towards, self._phys(t) + math.copysign(0.5, offset)):
            self._ref_fail(t)  # the compensation would go into a limit switch
            return
        h.phase = "offset"
        h.final = 0.0 if mode == "travel" else None
        speed = h.speed if self.description.twin.homing.offset_speed == "speed" else h.creep
        self.kin.move_to(t, self.kin.position(t) + offset, speed if speed > 0 else 1.0,
                         h.rate, h.rate)
        self._last_dir = 1 if offset > 0 else -1

    def _offset_home(self, speed: float, accel: Any, offset: float, now: float) -> None:
        """``behaviour = "move_to_offset"``: a move to the position ``offset`` at ``speed``;
        there it is homed. A limit switch met on the way stops it (as ``[twin] limits``
        say) and the homing fails."""
        ppr = self.pulses_per_rev
        rate = float(accel) * ppr if _finite_pos(accel) else math.inf
        pps = self._pps(speed)
        here = self.kin.position(now)
        if pps <= 0 or offset == here:
            self._set_counter(now, offset)
            self.homed = True
            return
        towards = "limit_positive" if offset > here else "limit_negative"
        if self._blocked(offset - here, now) or self._signal_at(
                towards, self._phys(now) + math.copysign(0.5, offset - here)):
            self.homing_failed = True
            return
        self._begin_ref(_RefHoming("", "offset", 1.0 if offset > here else -1.0, pps, pps,
                                   rate, offset), now)
        self.kin.move_to(now, offset, pps, rate, rate)
        self._last_dir = 1 if offset > here else -1

    def _ref_limits(self, t0: float, t1: float, *, reverse: bool = False,
                    offset: bool = False) -> list[tuple[float | None, _Handler]]:
        h = self._ref
        assert h is not None
        handler = self._ref_reverse if reverse else self._ref_fail
        return [(self._signal_edge(lim, True, t0, t1), handler)
                for lim in ("limit_positive", "limit_negative")
                if offset or lim != h.reference]
