"""``DescribedProfile``: the command engine, its rooms together.
"""

from __future__ import annotations

from drivebus.drives.command.base import ProfileBase
from drivebus.drives.command.homing import Homing
from drivebus.drives.command.motion import Commands
from drivebus.drives.command.procedures import Procedures
from drivebus.drives.command.programs import Programs
from drivebus.drives.command.setup import Setup
from drivebus.drives.command.status import Status
from drivebus.drives.command.writes import Writes


class DescribedProfile(Commands, Homing, Programs, Setup, Status, Writes, Procedures,
                       ProfileBase):
    """A profile that runs a drive description (the command engine)."""
