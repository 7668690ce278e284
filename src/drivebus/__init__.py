"""drivebus: Modbus stepper and servo drives on shared RS-485 lines and Modbus TCP, from asyncio."""

from drivebus import errors
from drivebus.bus import Bus, BusStats, Priority, SlaveHandle, SlaveStats
from drivebus.drives import DriveStatus
from drivebus.line import Exchange, Line, RtuOverTcpLine, SerialLine, TcpLine
from drivebus.motion import (
    Axis,
    AxisGroup,
    AxisState,
    Machine,
    MotionEvent,
    Recording,
    open_machine,
)
from drivebus.settings import LineSettings

__all__ = [
    "Axis",
    "AxisGroup",
    "AxisState",
    "Bus",
    "BusStats",
    "DriveStatus",
    "Exchange",
    "Line",
    "LineSettings",
    "Machine",
    "MotionEvent",
    "Priority",
    "Recording",
    "RtuOverTcpLine",
    "SerialLine",
    "SlaveHandle",
    "SlaveStats",
    "TcpLine",
    "errors",
    "open_machine",
]

__version__ = "0.1.0"
