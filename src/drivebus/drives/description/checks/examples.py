"""The cross-checks of ``[[examples]]``: frames of hex bytes, and the registers and
procedures each example names.
"""

from __future__ import annotations

import re

from drivebus.drives.description.checks.core import CheckCore
from drivebus.drives.description.procedures import PROCEDURES


class ExampleChecks(CheckCore):
    """The manual's example frames."""

    def _examples(self) -> None:
        for i, ex in enumerate(self.d.examples):
            where = f"examples[{i}]"
            for frame in [*ex.request, *ex.reply]:
                if not re.fullmatch(r"\s*(?:(?:0x)?[0-9A-Fa-f]{2}h?[\s,]*)+", frame):
                    self.out.append(f"{where}: {frame!r} is not a frame of hex bytes "
                                    f"('01 06 00 1D 02 58 D9 8B')")
                    break
            for key in ex.write or {}:
                self._target(f"{where}.write", key, set(), writes=True)
            for item in ex.read or []:
                if isinstance(item, str) and "[" in item:
                    self._target(f"{where}.read", item, set())
                else:
                    self._span(f"{where}.read", item)
            read_keys = {k for item in ex.read or [] for k in
                         ([item] if isinstance(item, str) else item)}
            for key in ex.values:
                if key not in read_keys and ex.read and not any(
                        isinstance(item, list) for item in ex.read):
                    self.out.append(f"{where}.values.{key}: not one of the registers read")
            if ex.procedure is not None and ex.procedure not in self.d.procedures and \
                    (self.d.drive.engine != "cia402" or ex.procedure not in PROCEDURES):
                self.out.append(f"{where}.procedure: no procedure {ex.procedure!r}")
