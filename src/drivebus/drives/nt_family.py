"""Rtelligent NT-family drives: the NT86 (Modbus RTU) and the EPR60/EPT60 (Modbus TCP).

Both run from their built-in drive descriptions (``drives/descriptions/nt86.toml``, which
``epr60.toml`` extends) on the command engine; this module keeps the names code imports:
the profile classes, the status bits, the alarm texts and the command codes.
"""

from __future__ import annotations

import enum
from collections.abc import Mapping, Sequence
from typing import Any

from drivebus.drives.engine import DescribedProfile, ReadPlan
from drivebus.drives.registry import FAMILIES
from drivebus.drives.status import DriveStatus
from drivebus.drives.values import Attrs

__all__ = [
    "ALARM_BITS",
    "CMD_ESTOP",
    "EPR60Profile",
    "NT86Profile",
    "StatusBit",
    "decode_alarm",
]

_NT86 = FAMILIES["NT86"]
_EPR60 = FAMILIES["EPR60"]
assert _NT86.spec is not None and _EPR60.spec is not None, "built in as descriptions"
_REGS = _NT86.spec.regs


StatusBit = enum.IntFlag("StatusBit", {name: _REGS["status"].bit_mask(name)
                                        for name in _REGS["status"].d.bits})
"""Bits of status register 1 (NT86 manual 2.6.1.2, EPR60 manual 3.3): the description's
``registers.status.bits`` (``StatusBit.MOV``)."""


_ALARMS = _NT86.spec.alarms
assert _ALARMS is not None
ALARM_BITS: dict[int, str] = {mask.bit_length() - 1: text for mask, text in
                              _ALARMS.texts.items()}
"""Bits of alarm register 0, with the manual's names."""

CMD_ESTOP = _NT86.spec.constants["CMD_ESTOP"]
"""Register 18's emergency-stop code."""


class NT86Profile(_NT86.profile):  # type: ignore[misc,valid-type]
    """Rtelligent NT86 over Modbus RTU: the command engine running ``nt86.toml``.

    ``decode_status`` also decodes the words of registers 0.. as one FC03 read them (the
    manual's example response), on a profile made without a drive (``__new__``).
    """

    def decode_status(self, values: Mapping[str, Any] | Sequence[int],
                      raw_words: Mapping[str, list[int]] | None = None, *,
                      requested_at: float | None = None) -> DriveStatus:
        """The engine's decoding of polled values, or of the words of registers 0.."""
        if isinstance(values, Mapping):
            return super().decode_status(values, raw_words, requested_at=requested_at)
        if "state" not in vars(self):  # a decoder only: the description's initial state
            d = self.description
            self.state = dict(d.state)
            self.learned, self.last = {}, {}
            self.option = Attrs("option", {k: o.default for k, o in d.options.items()})
            self.pulses_per_rev = d.units.pulses_per_rev.default
        words = dict(enumerate(values))
        regs = self.description.regs
        covered = [(reg, i) for reg, i in self._status_plan.regs
                   if all(a in words for a in reg.addresses())]
        decoded = self._decode(ReadPlan((), tuple(covered)), words)
        got = {reg.key: decoded.get(reg.key) for reg, _ in self._status_plan.regs}
        return super().decode_status(got, {k: [words[a] for a in regs[k].addresses()]
                                           for k in decoded})


_DECODER = NT86Profile.__new__(NT86Profile)  # alarm texts need only the description


def decode_alarm(word: int) -> str:
    """The alarm register's set bits as text ("" when no bit is set)."""
    return _DECODER.alarm_text(word) if word else ""


EPR60Profile: type[DescribedProfile] = _EPR60.profile
"""Rtelligent EPR60/EPT60 over Modbus TCP: the command engine running ``epr60.toml``."""
