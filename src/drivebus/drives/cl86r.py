"""CL86R closed-loop stepper drive: its description's profile and registers by old names.

The CL86R is a drive description (``drivebus/drives/descriptions/cl86r.toml``) run by the
command engine (``drivebus.drives.engine``); this module keeps the names code and tests
import.
"""

from __future__ import annotations

from drivebus.drives.registry import builtin_description, family
from drivebus.drives.units import ramp_time_ms

__all__ = [
    "ACCEL_TIME", "DECEL_TIME", "HOME_SPEED", "MAX_SPEED", "START_SPEED", "TARGET",
    "CL86RProfile", "ramp_time_ms",
]

_REGS = builtin_description("CL86R").regs

CL86RProfile = family("CL86R").profile
"""The CL86R's profile class (the command engine on its description)."""

START_SPEED = _REGS["start_speed"].register
ACCEL_TIME = _REGS["accel_time"].register
DECEL_TIME = _REGS["decel_time"].register
MAX_SPEED = _REGS["max_speed"].register
TARGET = _REGS["target"].register
HOME_SPEED = _REGS["home_speed"].register
