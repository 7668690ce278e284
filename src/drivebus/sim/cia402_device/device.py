"""``Cia402Device``: the simulated CiA 402 device, its rooms together.
"""

from __future__ import annotations

from drivebus.sim.cia402_device.base import DeviceBase
from drivebus.sim.cia402_device.homing import Homing
from drivebus.sim.cia402_device.machine import StateMachine
from drivebus.sim.cia402_device.profiles import Profiles


class Cia402Device(StateMachine, Profiles, Homing, DeviceBase):
    """A simulated CiA 402 drive: objects by name, state machine, PP, PV and homing."""
