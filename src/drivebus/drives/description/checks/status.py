"""The cross-checks of ``[identify]``, ``[units]``, ``[status]`` and
``[inputs]``/``[outputs]``: the registers they read and the names their expressions use.
"""

from __future__ import annotations

from drivebus.drives.base import describe_values
from drivebus.drives.description.checks.core import CheckCore
from drivebus.drives.description.registers import Reg
from drivebus.drives.description.status import IoDef
from drivebus.drives.units import Kind


class StatusChecks(CheckCore):
    """Identify, units, status and I/O."""

    def _units(self) -> None:
        ppr = self.d.units.pulses_per_rev
        if ppr.reg is not None:
            self._reg_key("units.pulses_per_rev.register", ppr.reg)
            if ppr.reg not in self.d.regs:
                return
        allowed = self.d.pulses_per_rev_allowed
        if ppr.default not in allowed:
            self.out.append(f"units.pulses_per_rev.default: the drive cannot be set to "
                            f"{ppr.default} pulses/rev (allowed: {describe_values(allowed)})")

    def _identify(self) -> None:
        ident = self.d.identify
        if ident is None:
            return
        for i, key in enumerate(ident.read):
            self._reg_key(f"identify.read[{i}]", key)
        self._names("identify.match", ident.match)
        self._names("identify.model", ident.model)
        self._names("identify.firmware", ident.firmware)
        for k, e in ident.raw.items():
            self._names(f"identify.raw.{k}", e)

    def _status(self) -> None:
        s = self.d.status
        for i, item in enumerate(s.poll):
            self._span(f"status.poll[{i}]", item)
        for i, extra in enumerate(s.extra):
            for j, item in enumerate(extra.read):
                self._span(f"status.extra[{i}].read[{j}]", item)
            self._names(f"status.extra[{i}].when", extra.when)
        for field in ("enabled", "moving", "in_position", "homed", "homing", "homing_error",
                      "alarm", "alarm_code", "limit_positive", "limit_negative", "position",
                      "velocity"):
            self._names(f"status.{field}", getattr(s, field))
        for k, e in s.raw.items():
            self._names(f"status.raw.{k}", e)
        self._status_units()
        if s.completion is not None:
            for j, item in enumerate(s.completion.read):
                self._span(f"status.completion.read[{j}]", item)
            for field in ("moving", "in_position", "alarm", "limit_positive", "limit_negative"):
                self._names(f"status.completion.{field}", getattr(s.completion, field))
        for k, e in s.track.items():
            self._names(f"status.track.{k}", e)
            if k not in self.d.state:
                self.out.append(f"status.track.{k}: no state variable {k!r} (declare it in "
                                f"[state])")

    def _status_units(self) -> None:
        """The position comes from a register in pulses, the velocity from one in a speed
        unit (or a register without a unit, taken as those): a register of another
        quantity (a current, a position for a speed) would be shown as what it is not."""
        for field, kind, units in (("position", Kind.POSITION, "pulses"),
                                   ("velocity", Kind.SPEED, "rpm, rps or pulses/s")):
            expr = self.d.status_exprs.get(field)
            reg = self.regs.get(expr.source.strip()) if expr is not None else None
            if reg is None or reg.codec.kind is kind or reg.array:
                continue
            if reg.codec.kind is Kind.PLAIN and not reg.d.unit:
                continue  # a raw count: the manual's unit is the field's
            given = getattr(self.d.status, field) is not None
            where = f"status.{field}" if given else f"registers.{reg.key}.means"
            self.out.append(f"{where}: register {reg.key} holds {_quantity(reg)}, not a "
                            f"{field} (give the {field} a register in {units})")

    def _io(self, where: str, io: IoDef | None) -> None:
        if io is None:
            return
        self._reg_key(f"{where}.state", io.state)
        for k in ("invert", "functions", "polarity"):
            v = getattr(io, k)
            if v is not None:
                self._reg_key(f"{where}.{k}", v)
        if io.functions is None and io.codes:
            self.out.append(f"{where}.codes: function codes need 'functions' (the registers "
                            f"that assign them); give fixed wiring with 'bits'")
        if io.functions is None and io.function_names:
            self.out.append(f"{where}.function_names: function names need 'functions' (the "
                            f"registers that assign them)")
        state = self.regs.get(io.state)
        if state is not None and len(io.names) > 16 * state.d.words:
            self.out.append(f"{where}.names: {len(io.names)} terminals for the "
                            f"{16 * state.d.words} bits of register {io.state}")
        funcs = self.regs.get(io.functions) if io.functions is not None else None
        if funcs is not None and io.names and len(io.names) != funcs.d.count:
            self.out.append(f"{where}.names: {len(io.names)} terminals, but register "
                            f"{io.functions} assigns {funcs.d.count} functions")
        if len(set(n.upper() for n in io.names)) != len(io.names):
            self.out.append(f"{where}.names: a terminal is named twice")


def _quantity(reg: Reg) -> str:
    """What a register holds, in an error: its kind and unit."""
    if reg.codec.kind is Kind.PLAIN:
        return f"a value in {reg.d.unit}"
    unit = f" ({reg.d.unit})" if reg.d.unit else ""
    return f"a {reg.codec.kind.value}{unit}"
