"""Which profile class belongs to a drive family name: the registry of drive families.

A sixth drive family is one profile module in ``drivebus.drives`` registered here (plus
its simulated twin in ``drivebus.sim.twins``, which the core never imports).
"""

from __future__ import annotations

from dataclasses import dataclass

from drivebus.drives.base import DriveProfile
from drivebus.drives.bhss import BHSSProfile
from drivebus.drives.cl86r import CL86RProfile
from drivebus.drives.nt_family import EPR60Profile, NT86Profile
from drivebus.drives.od_drive import ODDriveProfile
from drivebus.errors import ConfigError

__all__ = ["FAMILIES", "DriveFamily", "family"]


@dataclass(frozen=True)
class DriveFamily:
    """A drive family: its name, its profile and the link it uses."""

    name: str
    profile: type[DriveProfile]
    link: str
    """"rtu" or "tcp"."""
    description: str


FAMILIES: dict[str, DriveFamily] = {
    f.name: f
    for f in (
        DriveFamily("NT86", NT86Profile, "rtu", "Rtelligent NT86 RS-485 stepper drive"),
        DriveFamily("EPR60", EPR60Profile, "tcp", "EPR60/EPT60 Modbus TCP stepper drive"),
        DriveFamily("BHSS", BHSSProfile, "rtu", "Bholanath BHSS-100-MBUS stepper drive"),
        DriveFamily("CL86R", CL86RProfile, "rtu", "CL86R closed-loop stepper drive"),
        DriveFamily("OD2000", ODDriveProfile, "rtu",
                    "2000h object-dictionary drive (settings and monitoring only)"),
    )
}


def family(name: str) -> DriveFamily:
    """The family called ``name`` (case-insensitive); ConfigError listing the known ones."""
    f = FAMILIES.get(name.upper()) if isinstance(name, str) else None
    if f is None:
        raise ConfigError(f"unknown drive {name!r}: known drives are {', '.join(FAMILIES)}")
    return f
