"""What a described twin does when a register is written (``[twin] on_write``): its
triggers, their actions, the registers it sets itself, and the expressions they
evaluate (``_Scope``: registers, constants, the written value and the twin's state).
"""

from __future__ import annotations

import math
from collections.abc import Iterator, Mapping
from typing import Any

from drivebus.drives.description import Reg, Trigger
from drivebus.drives.expr import Expr, ExprError, Unknown
from drivebus.drives.values import Attrs, RegValue, Table
from drivebus.sim.described.base import TwinBase, _rate
from drivebus.sim.registers import SlaveException

_STARTS = {"move_absolute", "move_relative", "run", "home", "run_table"}


class Triggers(TwinBase):
    """A write's triggers and their actions; the twin's expressions."""

    def _act(self, reg: Reg, index: int | None, now: float,
             before: Mapping[int, int] | None = None) -> None:
        triggers = self._triggers.get(reg.key, ())
        if not triggers:
            return
        value = RegValue(self._raw(reg, index), reg)
        # `previous`: what the register held before this write (a start on a 0->1 edge)
        self._previous = RegValue(self._raw(reg, index, before), reg) if before is not None \
            else value
        try:
            for trig in triggers:
                if trig.when is not None and not self._eval(trig.when, now, value):
                    continue
                started = self._do(trig, value, now)
                self._set_registers(trig.set, now, value)  # what the drive writes back
                if trig.ends:
                    self._ends = (trig, value)
                    if not started:
                        self._settle(now)
                if not trig.more:
                    return
        finally:
            self._previous = None

    def _set_registers(self, sets: Mapping[str, Expr], now: float, value: Any) -> None:
        """Store raw values the drive writes itself (a trigger's ``set`` or ``ends``)."""
        for key, e in sets.items():
            target = self.description.regs[key]
            self._store(self.coils if target.d.coil else self.regs, target, None,
                        int(self._eval(e, now, value)) & (1 if target.d.coil else -1))

    def _running(self, now: float) -> bool:
        """A motion, homing or table runs (or the motor still turns)."""
        return self._homing is not None or self._ref is not None or \
            self._table is not None or self.kin.moving(now)

    def _settle(self, now: float) -> None:
        """Set the ``ends`` registers of the trigger whose motion is over by ``now``."""
        if self._ends is not None and not self._running(now):
            trig, value = self._ends
            self._ends = None
            self._set_registers(trig.ends, now, value)

    def _scope(self, now: float, value: Any = None,
               extra: Mapping[str, Any] | None = None) -> _Scope:
        return _Scope(self, now, value, extra)

    def _eval(self, e: Expr, now: float, value: Any = None,
              extra: Mapping[str, Any] | None = None) -> Any:
        try:
            return e(self._scope(now, value, extra))
        except Unknown as exc:
            raise ExprError(f"{e.source!r}: {exc}") from None

    def _param(self, trig: Trigger, name: str, now: float, value: Any) -> Any:
        e = getattr(trig, name)
        return None if e is None else self._eval(e, now, value)

    def _do(self, trig: Trigger, value: Any, now: float) -> bool:
        """Carry out ``trig``'s action; False if it is a start the drive did not obey."""
        do = trig.do
        refusals = self.description.link.refusals
        if do == "refuse":
            raise SlaveException(refusals.busy if refusals.busy is not None
                                 else refusals.value)
        if do in _STARTS and not self._eval(self.description.twin.starts, now, value):
            if trig.refuse and refusals.busy is not None:
                raise SlaveException(refusals.busy)
            return False
        p = self.pulses_per_rev
        if do in ("emergency_stop", "stop", "disable"):
            self._ref = None
            self._table = None
            self._completes = False
            self.stalled = False
        if do in ("emergency_stop", "stop"):  # an emergency stop without decel: at once
            self.stopping = do
            self._homing = None
            decel = self._param(trig, "decel", now, value)
            self.kin.stop(now, _rate(decel, p))
        elif do == "enable":
            self.enabled = True
        elif do == "disable":
            self.enabled = False
            self._homing = None
            self.kin.stop(now, None)  # released: the shaft is free, motion ends
        elif do == "clear_alarm":
            rule = self._clear_rule(self.alarm_code)
            if rule == "command":
                self.alarm_code = 0
        elif do == "zero_position":
            self._set_counter(now, 0)
        elif do == "set_position":
            self._set_counter(now, float(self._param(trig, "position", now, value)))
        elif do == "save":
            self.eeprom.update(self.regs)
        elif do == "factory_reset":
            self.regs.update(self.factory)
            self.eeprom.update(self.regs)
        elif do in ("move_absolute", "move_relative"):
            self._move(trig, value, now)
        elif do == "run":
            self._run(trig, value, now)
        elif do == "set_speed":
            self._set_speed(trig, value, now)
        elif do == "home":
            self._home(trig, value, now)
        elif do == "run_table":
            self._start_table(trig, value, now)
        return True

    def _clear_rule(self, code: int) -> str:
        alarms = self.description.alarms
        if alarms is None:
            return "command"
        return alarms.clears.get(code, "command")


class _Scope(Mapping[str, Any]):
    """The names a twin expression sees: registers (physical values), constants, the
    written ``value`` and the twin's state."""

    def __init__(self, twin: TwinBase, now: float, value: Any,
                 extra: Mapping[str, Any] | None = None) -> None:
        self._twin = twin
        self._now = now
        self._value = value
        self._extra = extra or {}

    def __getitem__(self, key: str) -> Any:
        t = self._twin
        d = t.description
        if key in self._extra:
            return self._extra[key]
        if key == "value":
            if self._value is None:
                raise KeyError(key)
            return self._value
        if key == "previous":
            if t._previous is None:
                raise KeyError(key)
            return t._previous
        if key in d.constants:
            return d.constants[key]
        reg = d.regs.get(key)
        if reg is not None:
            if reg.array:
                return Table(reg, {i: t.physical(reg, i, self._now) for i in reg.indices})
            return t.physical(reg, None, self._now)
        now = self._now
        state = {
            "enabled": lambda: t.enabled,
            "moving": lambda: t.kin.moving(now) or t._table is not None,
            "alarm": lambda: bool(t.alarm_code),
            "homed": lambda: t.homed,
            "homing": lambda: t._homing is not None or t._ref is not None,
            "motion": lambda: t.motion,
            "speed_now": lambda: t.speed_rpm(now),
            "motion_decel": lambda: None if t._motion_decel is None or not
            math.isfinite(t._motion_decel) else t._motion_decel / t.pulses_per_rev,
            "pulses_per_rev": lambda: t.pulses_per_rev,
            "limit_positive": lambda: t.switch_states(now)[2],
            "limit_negative": lambda: t.switch_states(now)[1],
            "stopping": lambda: t.stopping if t.kin.moving(now) else None,
            "at_speed": lambda: t._signals(now)["at_speed"],
            "cruising": lambda: t.kin.steady(now),
            "stalled": lambda: t.stalled,
            "active": lambda: Attrs("active", t._active(now)),
        }
        if key in state:
            return state[key]()
        if key == "raw":
            return Attrs("raw", {k: t._raw(r, None) for k, r in d.regs.items()
                                 if not r.array})
        raise KeyError(key)

    def __iter__(self) -> Iterator[str]:
        return iter(())

    def __len__(self) -> int:
        return 0
