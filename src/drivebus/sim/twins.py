"""Which simulated twin plays each drive family (the simulator's own registry).

The core's registry (``drivebus.drives.registry``) knows the profiles; the twins are the
simulator's business: a sixth drive family adds its twin here.
"""

from __future__ import annotations

from drivebus.errors import ConfigError
from drivebus.sim.drive import SimDrive
from drivebus.sim.drives.bhss import SimBHSS
from drivebus.sim.drives.cl86r import SimCL86R
from drivebus.sim.drives.nt_family import SimEPR60, SimNT86
from drivebus.sim.drives.od_drive import SimODDrive

__all__ = ["TWINS", "twin_class"]

TWINS: dict[str, type[SimDrive]] = {
    "NT86": SimNT86,
    "EPR60": SimEPR60,
    "BHSS": SimBHSS,
    "CL86R": SimCL86R,
    "OD2000": SimODDrive,
}
"""The twin class of each drive family, by the family's registry name."""


def twin_class(family: str) -> type[SimDrive]:
    """The twin of drive family ``family``; ``ConfigError`` if the simulator has none."""
    try:
        return TWINS[family.upper()]
    except KeyError:
        raise ConfigError(
            f"the simulator has no twin of drive {family!r} (it has {', '.join(TWINS)})"
        ) from None
