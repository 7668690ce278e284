"""The cross-checks of ``[procedures]`` and ``[programs]``: each step's registers,
blocks, calls, state variables and the names its expressions use.
"""

from __future__ import annotations

import re

from drivebus.drives.description.checks.core import CheckCore
from drivebus.drives.description.procedures import PROCEDURES, Procedure, Step
from drivebus.drives.description.registers import Reg
from drivebus.drives.expr import Expr


class ProcedureChecks(CheckCore):
    """Procedures, their steps, and programs."""

    def _programs(self) -> None:
        proc = self.d.procedures.get("retarget_absolute")
        if self.d.programs.retarget and (proc is None or proc.unsupported is not None):
            self.out.append("programs.retarget: needs procedures.retarget_absolute (the steps "
                            "that give a running move its new target)")

    def _procedure(self, name: str, proc: Procedure) -> None:
        where = f"procedures.{name}"
        params = set(PROCEDURES.get(name, ("", ()))[1]) | {p.name for p in proc.params}
        for i, taken in enumerate(proc.takes or []):
            if taken not in params:
                self.out.append(f"{where}.takes[{i}]: {taken!r} is no parameter of {name} "
                                f"({', '.join(sorted(params)) or 'it has none'})")
        self._names(f"{where}.supported", proc.supported)
        self._names(f"{where}.what", proc.what, params)
        if name == "learn":
            for i, step in enumerate(proc.steps):
                if step.action not in ("read", "set"):
                    self.out.append(f"{where}.steps[{i}]: learn only reads (it runs when a "
                                    f"viewing command opens the drive); write in setup")
        for i, step in enumerate(proc.steps):
            self._step(f"{where}.steps[{i}]", step, params)

    def _step(self, where: str, step: Step, params: set[str]) -> None:
        for field in ("when", "block", "check", "wait", "return_", "bits_set", "bits_clear",
                      "bits_toggle", "timeout"):
            self._names(f"{where}.{field.rstrip('_')}", getattr(step, field), params)
        self._names(f"{where}.fail", step.fail, params)
        self._names(f"{where}.message", step.message, params)
        if step.write is not None:
            if step.each is not None:
                name, _, source = step.each.partition(" in ")
                self._names(f"{where}.each", Expr.parse(source), params)
                params = params | {name.strip()}
            for key, item in step.write.items():
                self._target(f"{where}.write", key, params, writes=True)
                self._names(f"{where}.write.{key}", item.value, params)
                self._value_name(f"{where}.write.{key}", key, item.value, params)
            if step.block is not None and step.each is None:
                self._block(where, list(step.write))
        if step.read is not None:
            for j, item in enumerate(step.read):
                if isinstance(item, str) and "[" in item:
                    self._target(f"{where}.read[{j}]", item, params)
                else:
                    self._span(f"{where}.read[{j}]", item)
        if step.modify is not None:
            self._target(f"{where}.modify", step.modify, params, writes=True)
            reg = self.regs.get(step.modify.split("[", 1)[0].strip())
            if reg is not None and reg.space in (2, 3):
                self.out.append(f"{where}.modify: {reg.key} is a coil or discrete input: "
                                f"write it (0/1) instead")
        if step.call is not None and step.call not in self.d.procedures:
            self.out.append(f"{where}.call: no procedure {step.call!r}")
        for k, e in step.args.items():
            self._names(f"{where}.args.{k}", e, params)
        if step.set is not None:
            for k, e in step.set.items():
                if k not in self.d.state:
                    self.out.append(f"{where}.set.{k}: no state variable {k!r} (declare it "
                                    f"in [state])")
                self._names(f"{where}.set.{k}", e, params)

    def _value_name(self, where: str, key: str, value: Expr, params: set[str]) -> None:
        """A bare name written to a register with named ``values`` is read as the
        parameter, constant or register of that name, not as the named value: where it is
        both, say so (the named value is written as a text, ``"'name'"``)."""
        reg = self.regs.get(key.split("[", 1)[0].strip())
        name = value.source.strip()
        if reg is None or name not in reg.d.values:
            return
        meaning = ("parameter" if name in params else "constant" if name in self.d.constants
                   else "register" if name in self.regs else None)
        if meaning is not None:
            self.out.append(f"{where}: {name!r} is read as the {meaning} {name}, not as "
                            f"the register's value {name} = "
                            f"{reg.d.values[name]}: write \"'{name}'\" for the value (or "
                            f"the parameter's name differently)")

    def _block(self, where: str, keys: list[str]) -> None:
        """A step's ``block``: its registers must follow on from each other in the order
        listed (one FC16 writes them; anything else would merge what the manual keeps
        apart, or silently become several writes)."""
        from drivebus.drives.description.mapping import adjacent

        pairs: list[tuple[Reg, int | None]] = []
        for key in keys:
            m = re.fullmatch(r"([A-Za-z_][A-Za-z0-9_]*)(?:\[\s*(\d+)\s*\])?", key.strip())
            reg = self.regs.get(m.group(1)) if m is not None else None
            if m is None or reg is None or (reg.array and m.group(2) is None):
                return  # an index only the run knows, or a mistake named elsewhere
            index = int(m.group(2)) if m.group(2) is not None else None
            if index is not None and (not reg.array or index not in reg.indices):
                return
            pairs.append((reg, index))
        gap = adjacent(pairs)
        if gap is not None:
            self.out.append(
                f"{where}.block: {gap[0]} and {gap[1]} are not adjacent, so one FC16 "
                f"cannot write them: list a block's registers in address order with no "
                f"gap (and only where the manual lets them be written together), or "
                f"write them in separate steps")
