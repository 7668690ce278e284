"""Which profile class and which simulated twin belong to a drive family name."""

from __future__ import annotations

import importlib
from dataclasses import dataclass

from drivebus.drives.base import DriveProfile
from drivebus.errors import ConfigError
from drivebus.sim.drive import SimDrive

__all__ = ["FAMILIES", "DriveFamily", "family"]


@dataclass(frozen=True)
class DriveFamily:
    """A drive family: its profile, its simulated twin and the link it uses."""

    name: str
    profile_path: str
    sim_path: str
    link: str  # "rtu" or "tcp"
    description: str

    @staticmethod
    def _load(path: str) -> type:
        module, _, attr = path.partition(":")
        return getattr(importlib.import_module(module), attr)  # type: ignore[no-any-return]

    @property
    def profile(self) -> type[DriveProfile]:
        """The profile class."""
        return self._load(self.profile_path)

    @property
    def sim(self) -> type[SimDrive]:
        """The simulated twin's class."""
        return self._load(self.sim_path)


FAMILIES: dict[str, DriveFamily] = {
    f.name: f
    for f in (
        DriveFamily("NT86", "drivebus.drives.nt_family:NT86Profile",
                    "drivebus.sim.drives.nt_family:SimNT86", "rtu",
                    "Rtelligent NT86 RS-485 stepper drive"),
        DriveFamily("EPR60", "drivebus.drives.nt_family:EPR60Profile",
                    "drivebus.sim.drives.nt_family:SimEPR60", "tcp",
                    "EPR60/EPT60 Modbus TCP stepper drive"),
        DriveFamily("BHSS", "drivebus.drives.bhss:BHSSProfile",
                    "drivebus.sim.drives.bhss:SimBHSS", "rtu",
                    "Bholanath BHSS-100-MBUS stepper drive"),
        DriveFamily("CL86R", "drivebus.drives.cl86r:CL86RProfile",
                    "drivebus.sim.drives.cl86r:SimCL86R", "rtu",
                    "CL86R closed-loop stepper drive"),
        DriveFamily("OD2000", "drivebus.drives.od_drive:ODDriveProfile",
                    "drivebus.sim.drives.od_drive:SimODDrive", "rtu",
                    "2000h object-dictionary drive (settings and monitoring only)"),
    )
}


def family(name: str) -> DriveFamily:
    """The family called ``name`` (case-insensitive); ConfigError listing the known ones."""
    f = FAMILIES.get(name.upper())
    if f is None:
        raise ConfigError(f"unknown drive {name!r}: known drives are {', '.join(FAMILIES)}")
    return f
