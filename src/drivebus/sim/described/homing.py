"""A described twin's homing by CiA 402 method: the legs of the search (limit switches,
home switch edges, a cam), the description's methods and the side a home cam covers.
"""

from __future__ import annotations

import math
from typing import Any

from drivebus.clock import monotonic
from drivebus.drives.cia402 import HomeSignal, HomeSwitch, HomingMethod, homing_method
from drivebus.drives.description import HomingMethod as MethodDef
from drivebus.drives.description import Trigger
from drivebus.drives.expr import ExprError
from drivebus.errors import ArgumentError
from drivebus.sim.described.base import TwinBase, _finite_pos
from drivebus.sim.described.state import _Homing, _Phase


def _search_phases(method: int, home: bool, neg: bool, pos: bool
                   ) -> tuple[dict[str, _Phase], str] | None:
    """The legs of CiA 402 homing method ``method`` (``drivebus.drives.cia402``) and the
    first leg, given the switch states (home, negative limit, positive limit) at the start.

    The origin is the method's edge crossed in its final direction at the creep speed: a
    limit switch's edge (where it becomes inactive), or the home switch's lower or upper
    edge. The search runs at the fast speed in the method's initial direction (for a home
    switch that is a cam, where the switch's state says), reverses at the method's
    reversal limit switch, and backs off the edge to cross it again at the creep speed.
    Index pulses are not modelled (methods 1-14 home as 17-30).
    """
    try:
        m = homing_method(method)
    except ArgumentError:
        return None
    if m.signal is HomeSignal.NEGATIVE_LIMIT:
        legs = {"fast": _Phase(-1, True, (("limit_negative", "creep"),)),
                "creep": _Phase(+1, False, (("limit_negative", "done"),))}
        return legs, "creep" if neg else "fast"
    if m.signal is HomeSignal.POSITIVE_LIMIT:
        legs = {"fast": _Phase(+1, True, (("limit_positive", "creep"),)),
                "creep": _Phase(-1, False, (("limit_positive", "done"),))}
        return legs, "creep" if pos else "fast"
    if m.signal is not HomeSignal.HOME_SWITCH:
        return None
    edge = "home_high" if m.home_switch in (HomeSwitch.UPPER_EDGE, HomeSwitch.NEGATIVE) \
        else "home_low"
    f = m.final_direction
    # Crossing the edge moving f enters the switch (lower edge moving up, upper moving down)
    # or leaves it; entering needs a back-off to cross it again at the creep speed.
    entering = (edge == "home_low") == (f > 0)
    final = _Phase(f, False, ((edge, "done"),))
    legs: dict[str, _Phase] = {"final": final}
    if entering:
        legs["back"] = _Phase(-f, False, ((edge, "final"),))
        on_switch = "back"
    else:
        on_switch = "final"
    initial = m.initial_direction
    if m.home_switch in (HomeSwitch.POSITIVE, HomeSwitch.NEGATIVE):  # a cam on one side
        side = 1 if m.home_switch is HomeSwitch.POSITIVE else -1
        if not home:
            legs["fast"] = _Phase(side, True, ((edge, on_switch),))
            return legs, "fast"
        if f == -side:
            return legs, "final"  # leave the cam at the creep speed
        legs["off"] = _Phase(-side, True, ((edge, "final"),))
        return legs, "off"
    first_edge = "home_low" if initial > 0 else "home_high"
    other_edge = "home_high" if initial > 0 else "home_low"
    ahead = "limit_positive" if initial > 0 else "limit_negative"
    legs["fast"] = _Phase(initial, True, ((first_edge, on_switch), (ahead, "reverse")))
    legs["reverse"] = _Phase(-initial, True, ((other_edge, on_switch),))
    return legs, on_switch if home else "fast"


class Homing(TwinBase):
    """Homing by the CiA 402 method each description method names."""

    def home_side(self) -> int:
        """The side a home cam covers when ``home_cam`` does not say: the side the homing
        method in the drive's registers searches towards (+1 if none)."""
        try:
            method = self._method_def(self._method_code(monotonic()))
        except ExprError:  # the method depends on a write being made: the default side
            method = None
        if method is not None and method.behaviour == "reference_edge":
            return method.direction or 1
        m = _cia402_method(method)
        if m is None or m.home_switch is HomeSwitch.POSITIVE:
            return 1
        if m.home_switch is HomeSwitch.NEGATIVE:
            return -1
        return m.initial_direction or 1

    def _method_code(self, now: float) -> Any:
        """The homing method the drive's home trigger names now (its register's value)."""
        trig = next((t for ts in self._triggers.values() for t in ts if t.do == "home"), None)
        return None if trig is None else self._param(trig, "method", now, None)

    def _method_def(self, code: Any) -> MethodDef | None:
        """The description's homing method of ``code`` (a name or the drive's number)."""
        h = self.description.homing
        if h is None or code is None:
            return None
        if isinstance(code, str):
            return h.methods.get(code)
        return next((m for m in h.methods.values() if m.code is not None and
                     m.code == int(code)), None)

    def _home(self, trig: Trigger, value: Any, now: float) -> None:
        method = self._method_def(self._param(trig, "method", now, value))
        if method is None:
            return  # not a documented method: the drive does nothing
        ppr = self.pulses_per_rev
        speed = float(self._param(trig, "speed", now, value) or 0.0)
        creep = float(self._param(trig, "creep", now, value) or speed)
        accel = self._param(trig, "accel", now, value)
        offset = float(self._param(trig, "offset", now, value) or 0.0)
        self._wrap(now)
        self.motion = trig.motion or "homing"
        self.homed = False
        self.homing_failed = False
        self.stopping = None
        self._table = None
        if method.behaviour == "reference_edge":
            self._ref_home(method, speed, creep, accel, offset, now)
            return
        if method.behaviour == "move_to_offset":
            self._offset_home(speed, accel, offset, now)
            return
        if method.behaviour == "hard_stop":
            self._stop_home(method, speed, creep, accel, offset, now)
            return
        number = method.cia402
        if method.behaviour == "set" or number in (33, 34, 35, 37):
            self._set_counter(now, offset)
            self.homed = True
            return
        home, neg, pos = self.switch_states(now)
        plan = _search_phases(number or 0, home and self._wired("home_switch"),
                              neg and self._wired("limit_negative"),
                              pos and self._wired("limit_positive"))
        if plan is None:
            return
        phases, first = plan
        rate = float(accel) * ppr if _finite_pos(accel) else math.inf
        self._homing = _Homing(phases, first, now, self._pps(speed), self._pps(creep),
                               rate, offset)
        self._enter(first, now)

    def _enter(self, name: str, t: float) -> None:
        h = self._homing
        assert h is not None
        phase = h.phases[name]
        v = self.kin.velocity(t)
        self.kin.run(t, phase.direction * (h.speed if phase.fast else h.creep), h.rate, h.rate)
        h.t_dir = t + abs(v) / h.rate if v * phase.direction < 0 and h.rate > 0 else t
        h.phase = name

    def _next_edge(self, now: float) -> tuple[float, str] | None:
        h = self._homing
        assert h is not None
        phase = h.phases[h.phase]
        events = list(phase.events)
        ahead = "limit_positive" if phase.direction > 0 else "limit_negative"
        if all(name != ahead for name, _ in events):
            events.append((ahead, "abort"))
        t_from = h.t_dir + 1e-9
        best: tuple[float, str] | None = None
        for name, nxt in events:
            span = self._span(name)
            if name == ahead and span is not None and t_from <= now and \
                    span.active(self._phys(t_from)):
                return t_from, nxt  # the limit ahead is active as the leg sets off
            boundary = self._boundary(name)
            if boundary is None:
                continue
            tc = self.kin.crossing(boundary, t_from, now)
            if tc is not None and (best is None or tc < best[0]):
                best = (tc, nxt)
        return best

    def _advance_homing(self, now: float) -> None:
        for _ in range(16):
            h = self._homing
            if h is None:
                return
            edge = self._next_edge(now)
            if edge is None:
                return
            tc, nxt = edge
            if nxt == "done":
                self.kin.stop(tc, h.rate)
                self._set_counter(tc, h.offset)
                self.homed = True
                self._homing = None
            elif nxt == "abort":
                self.kin.stop(tc, self._limit_rate(tc))
                self._homing = None
                self.homing_failed = True
            else:
                self._enter(nxt, tc)


def _cia402_method(method: MethodDef | None) -> HomingMethod | None:
    """The CiA 402 method a description's homing method behaves as, if any."""
    if method is None or method.cia402 is None:
        return None
    try:
        return homing_method(method.cia402)
    except ArgumentError:
        return None
