"""SimBHSS: the simulated BHSS-100-MBUS, the generic twin of its built-in description
(``drivebus/drives/descriptions/bhss.toml``, whose ``[twin]`` section says how it behaves).

This module keeps the names tests import: the twin class and its factory line settings.
"""

from __future__ import annotations

from drivebus.drives.bhss import DESCRIPTION
from drivebus.settings import LineSettings
from drivebus.sim.described import DescribedDrive, twin_of

__all__ = ["FACTORY_SETTINGS", "SimBHSS"]

FACTORY_SETTINGS = LineSettings.parse(DESCRIPTION.link.factory or "9600 8N1")
"""SW6/SW7 ON with 0x0014 = 0 gives 9600; 0x0015 = 0 is 8N1 (manual §2.3.2, §2.4)."""

SimBHSS: type[DescribedDrive] = twin_of(DESCRIPTION)
"""Simulated BHSS-100-MBUS: map, exceptions, EEPROM, ramps in ms, homing, alarms."""
