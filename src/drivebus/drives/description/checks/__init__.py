"""The cross-checks pydantic cannot make, one room per section (``registers``,
``status``, ``procedures``, ``twin``, ``examples``) on common ground (``core``): they
need the whole description, so they sit above it (``drivebus.drives.description.model``);
a section's own rules are its models' validators, beside its fields.
"""

from __future__ import annotations

import difflib
from collections.abc import Iterator

from drivebus.drives.description.checks.examples import ExampleChecks
from drivebus.drives.description.checks.procedures import ProcedureChecks
from drivebus.drives.description.checks.registers import RegisterChecks
from drivebus.drives.description.checks.status import StatusChecks
from drivebus.drives.description.checks.twin import TwinChecks
from drivebus.drives.description.procedures import EXTRA_PROCEDURES, PROCEDURES


class Checker(RegisterChecks, StatusChecks, ProcedureChecks, TwinChecks, ExampleChecks):
    """The cross-checks pydantic cannot make: every name an expression uses exists, every
    register key named exists, tables and ramps refer to what they should."""

    def problems(self) -> Iterator[str]:
        d = self.d
        self._registers()
        self._names_apart()
        self._units()
        self._identify()
        self._status()
        self._io("inputs", d.inputs)
        self._io("outputs", d.outputs)
        if d.alarms is not None:
            self._reg_key("alarms.register", d.alarms.reg)
        for name, sig in d.signals.items():
            self._reg_key(f"signals.{name}.register", sig.reg)
        called = {step.call for proc in d.procedures.values() for step in proc.steps
                  if step.call is not None}
        for name, proc in d.procedures.items():
            self._procedure(name, proc)
            known = [*PROCEDURES, *EXTRA_PROCEDURES]
            close = difflib.get_close_matches(name, known, n=1, cutoff=0.8)
            if name not in known and name not in called and close:
                # the drive's own procedure (profile.NAME), but named like a common one
                self.out.append(f"procedures.{name}: did you mean {close[0]!r}? (the engine "
                                f"runs {close[0]}; a procedure of the drive's own needs a "
                                "name of its own)")
        for i, oc in enumerate(d.option_checks):
            self._names(f"option_checks[{i}].check", oc.check)
            self._names(f"option_checks[{i}].message", oc.message)
        self._programs()
        self._twin()
        if d.link.format_register is not None:
            self._reg_key("link.format_register", d.link.format_register)
        if d.link.baud_register is not None:
            self._reg_key("link.baud_register", d.link.baud_register)
        if d.link.address_register is not None:
            self._reg_key("link.address_register", d.link.address_register)
        if d.eeprom.write_through is not None:
            self._reg_key("eeprom.write_through.register", d.eeprom.write_through.reg)
        self._cia402()
        self._parameters()
        self._examples()
        yield from self.out
