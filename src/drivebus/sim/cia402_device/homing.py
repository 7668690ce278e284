"""Homing mode: the method's edges, the legs of the search, reversal at a limit switch,
the home position and the homing status bits.
"""

from __future__ import annotations

import functools
import math
from typing import Literal

from drivebus.drives.cia402 import HOMING_METHODS, HomeSignal, HomeSwitch, HomingMethod, Statusword
from drivebus.sim.cia402_device.base import DeviceBase
from drivebus.sim.cia402_device.state import _BAND, _Action, _Edge, _Events, _Homing, _Watch


class Homing(DeviceBase):
    """Homing by CiA 402 method."""

    def _home_edge(self, method: HomingMethod) -> _Edge | None:
        """The physical edge of the method's home signal (None where it has none here)."""
        s = self.setup
        if method.signal is HomeSignal.NEGATIVE_LIMIT and s.limit_negative is not None:
            return _Edge(s.limit_negative, -1, "negative limit")
        if method.signal is HomeSignal.POSITIVE_LIMIT and s.limit_positive is not None:
            return _Edge(s.limit_positive, +1, "positive limit")
        if method.signal is not HomeSignal.HOME_SWITCH or s.home_switch is None:
            return None
        if s.home_switch_width is not None:
            if method.home_switch is HomeSwitch.UPPER_EDGE:
                return _Edge(s.home_switch + s.home_switch_width, -1, "home switch upper edge")
            return _Edge(s.home_switch, +1, "home switch lower edge")
        return _Edge(s.home_switch, self.cam_side(), "home switch")

    def _start_homing(self, now: float) -> None:
        self.homed = False
        number = self.values["homing_method"]
        method = HOMING_METHODS.get(number)
        creep, fast = self._speed("homing_speed_zero"), self._speed("homing_speed_search")
        unable = self.kin.moving(now) or (method is not None and method.moves and (
            creep <= 0 or fast <= 0 or self._rate("homing_acceleration") is None))
        if method is None or unable:
            self._homing_result = "error"
            return
        if not method.moves:
            self._set_counter(now, self.values["home_offset"])
            self.homed = True
            self._homing_result = "attained"
            return
        self._homing_result = "none"
        f = method.final_direction
        edge = self._home_edge(method)
        watches = [self._watch("limit", e, now) for e in self._limit_edges() if e != edge]
        if method.signal is HomeSignal.INDEX_PULSE:
            index = _Edge(self._next_index(self._physical(now), f), 0, "index pulse")
            watches.append(_Watch("index", index, -f))
            self._homing = _Homing(method, f, watches, final=True, t_from=now)
            self._run_leg(now)
            return
        if edge is not None:
            watches.append(self._watch("home", edge, now))
        side = self._side(method, now)
        # On the side where the final approach ends: cross the edge the other way, which
        # starts the final approach; on the other side: go over it first. Unknown: search.
        direction = method.initial_direction if side is None else (-f if side == f else f)
        self._homing = _Homing(method, direction, watches, t_from=now)
        ahead = HomeSignal.POSITIVE_LIMIT if direction > 0 else HomeSignal.NEGATIVE_LIMIT
        if self._blocked(direction, now) and ahead is not method.signal:
            # Standing on the limit switch it would run into: its reversal limit turns it
            # round at once; any other is an error.
            if ahead is not method.reversal_limit:
                self._homing_error(now)
                return
            self._homing.direction, self._homing.reversed = -direction, True
        self._run_leg(now)

    def _watch(self, kind: Literal["home", "limit"], edge: _Edge, now: float) -> _Watch:
        """Watch ``edge`` from ``now``: the axis is on its active side where the switch is
        active (edges included), else on the other."""
        p = self._physical(now)
        active = (p - edge.position) * edge.active_side >= 0
        return _Watch(kind, edge, edge.active_side if active else -edge.active_side)

    def _side(self, method: HomingMethod, now: float) -> int | None:
        """On which side (+1/-1) of the homing edge the drive believes it is, from its
        inputs and the method's assumptions (None: it cannot tell, it searches)."""
        home, neg, pos = self._switches(now)
        if method.signal is HomeSignal.NEGATIVE_LIMIT:
            return -1 if neg else +1
        if method.signal is HomeSignal.POSITIVE_LIMIT:
            return +1 if pos else -1
        if method.home_switch is HomeSwitch.POSITIVE:
            return +1 if home else -1
        if method.home_switch is HomeSwitch.NEGATIVE:
            return -1 if home else +1
        if not home:
            return None
        return +1 if method.home_switch is HomeSwitch.LOWER_EDGE else -1

    def _next_index(self, p: float, direction: int) -> float:
        """The physical position of the first index pulse beyond ``p`` in ``direction``."""
        period, offset = self.setup.increments_per_rev, self.setup.index_offset
        k = (p - offset) / period
        n = math.floor(k) + 1 if direction > 0 else math.ceil(k) - 1
        return offset + n * period

    def _run_leg(self, t: float) -> None:
        h = self._homing
        assert h is not None
        speed = self._speed("homing_speed_zero" if h.final else "homing_speed_search")
        rate = self._rate("homing_acceleration")
        assert rate is not None
        self.kin.run(t, h.direction * speed, rate, rate)

    def _homing_event(self, now: float) -> tuple[float, _Action] | None:
        """The next edge the homing in progress passes up to ``now``, and what it does."""
        h = self._homing
        assert h is not None
        events = _Events()
        for w in h.watches:
            far = w.edge.position - w.side * _BAND + self._shift
            events.add(self.kin.crossing(far, h.t_from, now), functools.partial(self._passed, w))
        return events.first()

    def _passed(self, w: _Watch, tc: float) -> None:
        """The axis passed ``w``'s edge at ``tc`` (moving toward -w.side)."""
        h = self._homing
        assert h is not None
        moving = w.side = -w.side
        h.t_from = tc
        if w.kind == "index":
            self._home_found(tc, w.edge.position)
        elif w.kind == "limit":
            if moving != w.edge.active_side:
                return  # it left the limit switch
            into = HomeSignal.NEGATIVE_LIMIT if moving < 0 else HomeSignal.POSITIVE_LIMIT
            if into is h.method.reversal_limit and not h.reversed:
                h.reversed, h.direction = True, -h.direction
                self._run_leg(tc)
            else:
                self._homing_error(tc)
        else:
            self._home_edge_passed(w, moving, tc)

    def _home_edge_passed(self, w: _Watch, moving: int, tc: float) -> None:
        h = self._homing
        assert h is not None
        f = h.method.final_direction
        if h.final and moving == f:
            if not h.method.index_pulse:
                self._home_found(tc, w.edge.position)
                return
            index = _Edge(self._next_index(w.edge.position, f), 0, "index pulse")
            h.watches = [x for x in h.watches if x.kind != "home"] + [_Watch("index", index, -f)]
            return
        if moving == -f:  # now on the side the final approach starts from
            h.final, h.direction = True, f
        else:
            h.final, h.direction = False, -f
        self._run_leg(tc)

    def _home_found(self, tc: float, home: float) -> None:
        """The home position (physical) was passed at ``tc``: it reads the home offset; the
        axis comes to rest on the homing acceleration."""
        self.kin.stop(tc, self._rate("homing_acceleration"))
        past = self._physical(tc) - home
        self._set_counter(tc, self.values["home_offset"] + past)
        self.homed = True
        self._homing = None
        self._homing_result = "attained"

    def _homing_error(self, tc: float) -> None:
        self.kin.stop(tc, self._rate("quick_stop_deceleration"))
        self._homing = None
        self._homing_result = "error"

    def _homing_bits(self, moving: bool) -> int:
        reached = 0 if moving else Statusword.TARGET_REACHED
        if self._homing is not None:
            return 0
        if self._homing_result == "attained":
            return Statusword.HOMING_ATTAINED | reached
        if self._homing_result == "error":
            return Statusword.HOMING_ERROR | reached
        return reached
