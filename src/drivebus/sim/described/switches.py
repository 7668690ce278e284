"""The switches a described twin sees: home and limit switches direct or wired to input
terminals (``[twin] wiring``, the terminals' functions and polarity), their levels at a
position, and when the motion crosses an edge of one.
"""

from __future__ import annotations

import math
from collections.abc import Callable

from drivebus.sim.described.base import TwinBase
from drivebus.sim.drive import Span


class Switches(TwinBase):
    """Home and limit switches, wired or direct: levels, edges, signals."""

    def switch_states(self, now: float) -> tuple[bool, bool, bool]:
        """(home, limit negative, limit positive) at the physical position (with
        ``[twin] wiring``: as the drive sees them through its input functions)."""
        p = self._phys(now)
        if self.description.twin.wiring:
            return (self._signal_at("home_switch", p), self._signal_at("limit_negative", p),
                    self._signal_at("limit_positive", p))
        return self.switches_at(p)

    def _terminal(self, signal: str) -> int | None:
        """The bit of the terminal switch ``signal`` is wired to (None: not wired)."""
        d = self.description
        t = d.twin.wiring.get(signal)  # type: ignore[call-overload]
        if t is None:
            return None
        if isinstance(t, str):
            assert d.inputs is not None
            return d.inputs.names.index(t)
        return int(t)

    def _wire_switches(self) -> None:
        """Each switch the setup gives is wired to its terminal, whose function register
        is set to the switch's code (as the machine's builder configured it)."""
        d = self.description
        io = d.inputs
        if not d.twin.wiring or io is None or io.functions is None:
            return
        reg = d.regs[io.functions]
        given = {"home_switch": self.home_switch, "limit_positive": self.limit_positive,
                 "limit_negative": self.limit_negative}
        for signal in d.twin.wiring:
            bit = self._terminal(signal)
            if bit is None or signal not in io.codes:
                continue
            index = reg.indices[bit]
            self._store(self.regs, reg, index, io.codes[signal] if given[signal] is not None
                        else self._raw(reg, index))

    def _terminals(self) -> range:
        io = self.description.inputs
        return range(len(io.names) if io is not None and io.names else 16)

    def _switch_span(self, index: int) -> Span | None:
        for signal in self.description.twin.wiring:
            if self._terminal(signal) == index:
                if signal == "home_switch":
                    return self.home_span()
                return self.limit_span(1 if signal == "limit_positive" else -1)
        return None

    def _physical(self, index: int, p: float) -> bool:
        if self._external >> index & 1:
            return True
        span = self._switch_span(index)
        return span is not None and span.active(p)

    def _inverted(self, index: int, *, by_function: bool = True) -> bool:
        """Terminal ``index`` is inverted by the ``[inputs] polarity`` register, or (with
        ``by_function``) by the polarity bit of its function entry."""
        d = self.description
        io = d.inputs
        if io is None:
            return False
        inverted = io.polarity is not None and bool(
            self._raw(d.regs[io.polarity], None) >> index & 1)
        if by_function and io.polarity_bit is not None and io.functions is not None:
            reg = d.regs[io.functions]
            if index < len(reg.indices):
                inverted ^= bool(self._raw(reg, reg.indices[index]) & io.polarity_bit)
        return inverted

    def _level(self, index: int, p: float) -> bool:
        """The valid level of terminal ``index`` at physical position ``p`` (after the
        ``[inputs] polarity`` register or polarity bit)."""
        return self._physical(index, p) != self._inverted(index)

    def _carriers(self, signal: str) -> list[int]:
        """The terminals whose function is ``signal`` (or the one it is wired to)."""
        io = self.description.inputs
        if io is None or io.functions is None or signal not in io.codes:
            bit = self._terminal(signal)
            return [] if bit is None else [bit]
        reg = self.description.regs[io.functions]
        code = io.codes[signal]
        mask = io.function_mask
        return [n for n, i in enumerate(reg.indices) if self._raw(reg, i) & mask == code]

    def _direct_span(self, signal: str) -> Span | None:
        """The switch of ``signal`` if the drive sees it directly (``[twin] direct``)."""
        if signal not in self.description.twin.direct:
            return None
        if signal == "home_switch":
            return self.home_span()
        return self.limit_span(1 if signal == "limit_positive" else -1)

    def _signal_at(self, signal: str, p: float) -> bool:
        if signal in self.description.twin.direct:
            span = self._direct_span(signal)
            return span is not None and span.active(p)
        return any(self._level(i, p) for i in self._carriers(signal))

    def _signal_edge(self, signal: str, rising: bool, t0: float, t1: float) -> float | None:
        """First time in [t0, t1] a terminal carrying ``signal`` turns valid (or invalid)."""
        if signal in self.description.twin.direct:
            span = self._direct_span(signal)
            found = [] if span is None else [self._span_edge(span, span.active, rising, t0, t1)]
        else:
            found = [self._terminal_edge(i, rising, t0, t1) for i in self._carriers(signal)]
        times = [t for t in found if t is not None]
        return min(times) if times else None

    def _terminal_edge(self, index: int, rising: bool, t0: float, t1: float) -> float | None:
        span = self._switch_span(index)
        if span is None:
            return None
        return self._span_edge(span, lambda p: self._level(index, p), rising, t0, t1)

    def _span_edge(self, span: Span, level: Callable[[float], bool], rising: bool,
                   t0: float, t1: float) -> float | None:
        """First time in [t0, t1] ``level`` (of the physical position) turns valid (or
        invalid) at an end of ``span``."""
        xs = tuple(x for x in (span.lo, span.hi) if math.isfinite(x))
        found = [self._threshold_edge(level, x + self._shift, rising, t0, t1) for x in xs]
        times = [t for t in found if t is not None]
        return min(times) if times else None

    def _threshold_edge(self, level: Callable[[float], bool], x: float, rising: bool,
                        t0: float, t1: float) -> float | None:
        """First time in [t0, t1] ``level`` turns valid (or invalid) as the motor passes
        ``x`` (counter frame)."""
        t = t0
        while t <= t1:
            tc = self.kin.crossing(x, t, t1)
            if tc is None:
                return self._boundary_edge(level, rising, t, t1)
            # at a start from rest (or a turnaround) the way it leaves counts; resting on
            # the edge crosses nothing
            v = self.kin.velocity(tc) or self.kin.velocity(tc + 1e-6)
            if v == 0.0:
                return None
            step = math.copysign(0.5, v)
            p = x - self._shift
            if level(p - step) != level(p + step) and level(p + step) == rising:
                return tc
            t = tc + 1e-6
        return None

    def _boundary_edge(self, level: Callable[[float], bool], rising: bool, t0: float,
                       t1: float) -> float | None:
        """An edge in [t0, t1] that ``Kinematics.crossing`` missed where one motion segment
        hands over to the next on the switch's end (float rounding): the levels at both
        ends differ, bisection finds the time."""
        def level_at(t: float) -> bool:
            return level(self._phys(t))

        start = level_at(t0)
        if start == level_at(t1) or level_at(t1) != rising:
            return None
        lo, hi = t0, t1
        for _ in range(64):
            mid = 0.5 * (lo + hi)
            if mid in (lo, hi):
                break
            if level_at(mid) == start:
                lo = mid
            else:
                hi = mid
        return hi

    def _on_edge(self, signal: str, x: float) -> float:
        """``x`` (counter frame) on the nearest end of ``signal``'s switch when it is that
        close (the edge a crossing time found, without its float rounding)."""
        span = self._direct_span(signal) if signal in self.description.twin.direct else \
            next((self._switch_span(i) for i in self._carriers(signal)), None)
        if span is None:
            return x
        ends = [e + self._shift for e in (span.lo, span.hi) if math.isfinite(e)]
        near = min(ends, key=lambda e: abs(e - x), default=x)
        return near if abs(near - x) < 1e-3 else x

    def _wired(self, signal: str) -> bool:
        """True if an input carries ``signal`` (home_switch, limit_positive, ...)."""
        io = self.description.inputs
        if io is None or signal in self.description.twin.direct:
            return True
        if signal in io.bits:
            return True
        if io.functions is None or signal not in io.codes:
            return False
        reg = self.description.regs[io.functions]
        code = io.codes[signal]
        return any(self._raw(reg, i) & io.function_mask == code for i in reg.indices)

    def _span(self, edge: str) -> Span | None:
        """Where the switch of ``edge`` is active (physical), if the drive can see it."""
        signal = "home_switch" if edge.startswith("home") else edge
        if not self._wired(signal):
            return None
        if signal == "home_switch":
            return self.home_span()
        return self.limit_span(1 if signal == "limit_positive" else -1)

    def _boundary(self, edge: str) -> float | None:
        """Counter position of a switch edge the drive can see, or None (an edge at
        infinity: a cam's or a limit's outer end)."""
        span = self._span(edge)
        if span is None:
            return None
        pos = span.hi if edge in ("home_high", "limit_negative") else span.lo
        return pos + self._shift if math.isfinite(pos) else None

    def _signals(self, now: float) -> dict[str, bool]:
        home, neg, pos = self.switch_states(now)
        moving = self.kin.moving(now) or self._table is not None
        alarm = bool(self.alarm_code)
        at_speed = moving and self.motion == "speed" and self.kin.cruising(now)
        return {
            "enabled": self.enabled, "disabled": not self.enabled, "moving": moving,
            "at_rest": not moving, "in_position": not moving and not alarm,
            "homed": self.homed, "alarm": alarm,
            "homing": self._homing is not None or self._ref is not None,
            "reached": not moving and (self.reached or self._completes),
            "no_alarm": not alarm, "limit_positive": pos, "limit_negative": neg,
            "home_switch": home, "at_speed": bool(at_speed), "ready": True,
            "jogging": moving and self.motion == "speed",
        }

    def _active(self, now: float) -> dict[str, bool]:
        """Each input function of ``[inputs] codes``: active now."""
        io = self.description.inputs
        p = self._phys(now)
        return {} if io is None else {s: self._signal_at(s, p) for s in io.codes}
