"""Simulated twins of the Rtelligent NT-family drives, ``SimNT86`` and ``SimEPR60``: the
generic twins of their built-in descriptions (``drivebus/drives/descriptions/nt86.toml``
and ``epr60.toml``, whose ``[twin]`` sections say how each behaves, with the choices made
where the manuals are silent)."""

from __future__ import annotations

from typing import ClassVar

from drivebus.drives.registry import builtin_description
from drivebus.sim.described import twin_of

__all__ = ["SimEPR60", "SimNT86"]

_NT86 = builtin_description("NT86")
_EPR60 = builtin_description("EPR60")


class SimNT86(twin_of(_NT86)):  # type: ignore[misc]
    """Simulated Rtelligent NT86: Modbus RTU at 8N1 only, 9600/19200/38400/115200 baud,
    addresses 1-31. Options: ``home_cam``, ``home_switch_width``, ``hard_stop_negative`` /
    ``hard_stop_positive`` (end stops for hard-stop homing, closed loop only) and
    ``control_mode`` (register 22 at power-up: 0 open loop, 1/2 closed loop)."""

    drive_id: ClassVar[int] = _NT86.regs["drive_id"].d.default
    """What register 93 reads (the manual leaves its format open)."""


class SimEPR60(twin_of(_EPR60)):  # type: ignore[misc]
    """Simulated Rtelligent EPR60/EPT60: the generic twin of its built-in description."""

    drive_id: ClassVar[int] = _EPR60.regs["drive_id"].d.default
    """What register 93 reads (the manual leaves its format open)."""
