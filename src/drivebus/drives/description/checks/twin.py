"""The cross-checks of ``[twin]``: its triggers' registers, actions and parameters, its
wiring, and the names its expressions use (the twin's state among them).
"""

from __future__ import annotations

from drivebus.drives.description.checks.core import CheckCore
from drivebus.drives.description.twin import TWIN_ACTIONS, InputTrigger

_TWIN_NAMES = {"enabled", "moving", "alarm", "homed", "motion", "value", "previous", "raw",
               "speed_now", "pulses_per_rev", "limit_positive", "limit_negative", "motion_decel",
               "homing", "stopping", "active", "at_speed", "stalled", "cruising"}


class TwinChecks(CheckCore):
    """The twin's behaviour."""

    def _twin(self) -> None:
        t = self.d.twin
        names = _TWIN_NAMES
        for key, reg in self.d.registers.items():
            self._names(f"registers.{key}.valid", reg.valid, names)
        io = self.d.inputs
        for signal, terminal in t.wiring.items():
            if io is None:
                self.out.append(f"twin.wiring.{signal}: needs [inputs]")
            elif isinstance(terminal, str) and terminal not in io.names:
                self.out.append(f"twin.wiring.{signal}: no terminal {terminal!r} in "
                                f"inputs.names ({', '.join(io.names) or 'none'})")
        self._names("twin.starts", t.starts, names)
        self._names("twin.limits.stop", t.limits.stop, names)
        self._names("twin.limits.decel", t.limits.decel, names)
        self._names("twin.eeprom_write_through", t.eeprom_write_through, names)
        self._names("twin.enabled", t.enabled, names)
        self._names("twin.stall_time", t.stall_time, names)
        self._names("twin.homing.reverse_at_limit", t.homing.reverse_at_limit, names)
        self._names("twin.homing.offset", t.homing.offset, names)
        for key, reg in self.d.registers.items():
            for bit, b in reg.bits.items():
                self._names(f"registers.{key}.bits.{bit}.twin", b.twin, names)
        for i, key in enumerate(t.options):
            self._reg_key(f"twin.options[{i}]", key)
        out = self.d.outputs
        if out is not None and out.values is not None:
            self._reg_key("outputs.values", out.values)
        codes = io.codes if io is not None else {}
        for i, itrig in enumerate(t.on_input):
            if itrig.input not in codes:
                self.out.append(f"twin.on_input[{i}].input: no input function "
                                f"{itrig.input!r} in inputs.codes ({', '.join(codes) or 'none'})")
        triggers = [(f"twin.on_write[{i}]", trig) for i, trig in enumerate(t.on_write)]
        triggers += [(f"twin.on_input[{i}]", trig) for i, trig in enumerate(t.on_input)]
        for where, trig in triggers:
            if trig.reg or not isinstance(trig, InputTrigger):
                self._reg_key(f"{where}.register", trig.reg)
            self._names(f"{where}.when", trig.when, names)
            for kind, sets in (("set", trig.set), ("ends", trig.ends)):
                for key, e in sets.items():
                    self._reg_key(f"{where}.{kind}.{key}", key)
                    self._names(f"{where}.{kind}.{key}", e, names)
            allowed = TWIN_ACTIONS[trig.do]
            row_names = names | {"row"} if trig.do == "run_table" else names
            for field in ("target", "distance", "speed", "accel", "decel", "creep", "method",
                          "offset", "position", "rows", "wait", "repeat"):
                e = getattr(trig, field)
                if e is None:
                    continue
                if field not in allowed:
                    self.out.append(f"{where}.{field}: action {trig.do} takes "
                                    f"{', '.join(allowed) or 'no parameters'}")
                self._names(f"{where}.{field}", e, row_names)
            if trig.do == "run_table" and (trig.rows is None or trig.speed is None or
                                           (trig.target is None and trig.distance is None)):
                self.out.append(f"{where}: run_table needs rows, speed and a target or "
                                "distance")
