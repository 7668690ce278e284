"""The built-in simulator: virtual RS-485 wires with simulated slaves and drives."""

from drivebus.sim.drive import SimDrive
from drivebus.sim.harness import sim_bus
from drivebus.sim.segment import Segment
from drivebus.sim.slave import Fault, FaultPlan, RegisterSlave, SimSlave, SlaveException
from drivebus.sim.tcp import SimSerialServer, SimTcpServer
from drivebus.sim.wire import VirtualWire, WireFrame, lookup_wire

__all__ = [
    "Fault",
    "FaultPlan",
    "RegisterSlave",
    "Segment",
    "SimDrive",
    "SimSerialServer",
    "SimSlave",
    "SimTcpServer",
    "SlaveException",
    "VirtualWire",
    "WireFrame",
    "lookup_wire",
    "sim_bus",
]
