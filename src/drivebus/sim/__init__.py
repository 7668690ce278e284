"""The built-in simulator: virtual RS-485 wires with simulated slaves and drives."""

from drivebus.sim.slave import Fault, FaultPlan, RegisterSlave, SimSlave, SlaveException
from drivebus.sim.wire import VirtualWire, WireFrame, lookup_wire

__all__ = [
    "Fault",
    "FaultPlan",
    "RegisterSlave",
    "SimSlave",
    "SlaveException",
    "VirtualWire",
    "WireFrame",
    "lookup_wire",
]
