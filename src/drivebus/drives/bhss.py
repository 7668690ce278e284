"""The Bholanath BHSS-100-MBUS: its profile is its built-in description
(``drivebus/drives/descriptions/bhss.toml``) run by the command engine.

This module keeps the names code and tests import: the profile class, the register map
by the manual's names (``Regs``) and the tables of the description.
"""

from __future__ import annotations

from drivebus.drives.description import Description
from drivebus.drives.engine import DescribedProfile
from drivebus.drives.registers import Register
from drivebus.drives.registry import builtin_description, family
from drivebus.drives.units import ramp_time_ms

__all__ = [
    "ALARM_TEXTS",
    "EXCEPTION_TEXTS",
    "INPUT_FUNCTIONS",
    "INPUT_TERMINALS",
    "MICROSTEP_TABLE",
    "BHSSProfile",
    "Regs",
]

DESCRIPTION: Description = builtin_description("BHSS")
"""The BHSS's built-in description."""

_BASE: type[DescribedProfile] = family("BHSS").profile


class BHSSProfile(_BASE):  # type: ignore[misc,valid-type]
    """Profile of the Bholanath BHSS-100-MBUS, run from its description."""

    ramp_ms = staticmethod(ramp_time_ms)
    """The ramp time (ms) register ``reg`` takes to reach a speed at a rate, range-checked."""


def _reg(key: str) -> Register:
    return DESCRIPTION.regs[key].register


class Regs:
    """BHSS registers by the manual's names (from the description)."""

    MODEL = _reg("model")
    ERROR_CODE = _reg("error_code")
    STATUS = _reg("status")
    POSITION = _reg("position")
    MICROSTEP = _reg("microstep")
    EEPROM_UPDATE = _reg("eeprom_update")
    START_SPEED = _reg("start_speed")
    ACCEL_TIME = _reg("accel_time")
    DECEL_TIME = _reg("decel_time")
    MAX_SPEED = _reg("max_speed")
    DISTANCE = _reg("distance")
    START = _reg("start")
    STOP = _reg("stop")
    ENABLE = _reg("enable")
    HOME_MODE = _reg("home_mode")
    HOME_RAMP = _reg("home_ramp")


MICROSTEP_TABLE: tuple[int, ...] = DESCRIPTION.regs["microstep"].codec.table
"""Pulses per revolution for each value of register 0x0011 (index = register value)."""
INPUT_TERMINALS: tuple[str, ...] = tuple(DESCRIPTION.regs["input_function"].d.names)
"""Input terminals in the order of their function registers 0x0041.. and of 0x0008's bits."""
INPUT_FUNCTIONS: dict[str, int] = dict(DESCRIPTION.regs["input_function"].d.values)
"""Input function codes of registers 0x0041..0x0047."""
EXCEPTION_TEXTS: dict[int, str] = dict(DESCRIPTION.link.exceptions)
"""The BHSS's own meanings of exception codes 01-07 (manual Table 11)."""
ALARM_TEXTS: dict[int, str] = dict(DESCRIPTION.alarms.texts) if DESCRIPTION.alarms else {}
"""Alarm codes of register 0x0006."""
