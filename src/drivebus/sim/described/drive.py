"""``DescribedDrive``: the generic twin, its rooms together.
"""

from __future__ import annotations

from drivebus.sim.described.base import TwinBase
from drivebus.sim.described.homing import Homing
from drivebus.sim.described.io import Terminals
from drivebus.sim.described.motion import Motion
from drivebus.sim.described.power import Power
from drivebus.sim.described.reference import ReferenceHoming
from drivebus.sim.described.registers import Registers
from drivebus.sim.described.switches import Switches
from drivebus.sim.described.tables import Tables
from drivebus.sim.described.triggers import Triggers


class DescribedDrive(Terminals, Tables, ReferenceHoming, Homing, Motion, Triggers, Registers,
                     Switches, Power, TwinBase):
    """A simulated drive that plays a drive description."""
