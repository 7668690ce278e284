"""A described twin's alarms and power: an alarm latched, a power cut and restore (the
stored words back, the line settings its registers set applied).
"""

from __future__ import annotations

from drivebus.clock import monotonic
from drivebus.settings import LineSettings
from drivebus.sim.described.base import TwinBase, _formats_at
from drivebus.sim.drive import time_or_present


class Power(TwinBase):
    """Alarms, power loss and restore, and the line settings its registers set."""

    def raise_alarm(self, code: int, now: float | None = None) -> None:
        """Latch alarm ``code``: the motor stops at once."""
        t = time_or_present(now)
        self.advance(t)
        self._homing = None
        self._ref = None
        self._table = None
        self.stalled = False
        self._completes = False
        alarms = self.description.alarms
        if alarms is not None and alarms.kind == "flags":
            code |= self.alarm_code  # flags latch side by side
        super().raise_alarm(code, t)

    def power_loss(self) -> None:
        """Power cut: motion, homing and tables end with it (silent until restored)."""
        self.advance(monotonic())
        self._homing = None
        self._ref = None
        self._table = None
        super().power_loss()

    def supply_recovered(self) -> None:
        """The supply is back in range: alarms that clear with the supply clear."""
        if self._clear_rule(self.alarm_code) == "supply":
            self.alarm_code = 0

    def power_restore(self) -> None:
        """Power-up: stored words come back, volatile registers take their defaults, a
        stored line format applies, the counter starts at 0, the homed state is gone."""
        super().power_restore()
        now = monotonic()
        self.regs = dict(self.eeprom)
        self.coils = {}
        self._factory_words()  # the coils' defaults
        for reg in self.description.regs.values():
            if reg.d.volatile:
                for index in (reg.indices if reg.array else [None]):
                    self._store(self.regs, reg, index, reg.default_at(index))
        self._apply_baud_register(initial=False)
        self._apply_format_register(initial=False)
        if self.soft_address:
            key = self.description.link.address_register
            assert key is not None
            self.address = self._raw(self.description.regs[key], None)
        self.kin.hold(now)
        self._set_counter(now, 0)
        self.alarm_code = 0
        self.motion = None
        self.homed = False
        self._homing = None
        self._ref = None
        self._table = None
        self._ends = None
        self.reached = True
        self._completes = False
        self.stopping = None
        self.stalled = False
        self._functions_seen = self._input_functions(now)
        self.enabled = bool(self._eval(self.description.twin.enabled, now))

    def _apply_baud_register(self, *, initial: bool) -> None:
        """The baud rate register (``[link] baud_register``): a twin built at one of its
        named rates runs at the register's rate (its switches select the register): the
        rate is stored at first and the saved one applies at power-up. At another rate
        (set by switches) the register is not used."""
        d = self.description
        key = d.link.baud_register
        if key is None or self.settings is None:
            return
        reg = d.regs[key]
        if initial:
            code = reg.d.values.get(str(self.settings.baudrate))
            self._baud_by_register = code is not None
            if code is not None:
                self._store(self.regs, reg, None, code)
            return
        if not self._baud_by_register:
            return
        baud = {v: k for k, v in reg.d.values.items()}.get(self._raw(reg, None), "")
        if baud.isdigit():
            self.settings = LineSettings.parse(self.settings.format, baudrate=int(baud))

    def _apply_format_register(self, *, initial: bool) -> None:
        """The line format register: set from the settings at first, applied at power-up."""
        d = self.description
        key = d.link.format_register
        if key is None or self.settings is None:
            return
        reg = d.regs[key]
        values = reg.d.values
        allowed = _formats_at(d, self.settings.baudrate)
        if initial:
            code = values.get(self.settings.format, 0) if self.settings.format in allowed \
                else 0
            self._store(self.regs, reg, None, code)
            return
        names = {v: k for k, v in values.items()}
        fmt = names.get(self._raw(reg, None))
        if fmt is not None and fmt in allowed:
            self.settings = LineSettings.parse(fmt, baudrate=self.settings.baudrate)
