"""drivebus: Modbus stepper and servo drives on shared RS-485 lines and Modbus TCP, from asyncio."""

from drivebus import errors
from drivebus.bus import Bus, BusStats, Priority, SlaveHandle, SlaveStats
from drivebus.line import Exchange, Line, RtuOverTcpLine, SerialLine, TcpLine
from drivebus.settings import LineSettings

__all__ = [
    "Bus",
    "BusStats",
    "Exchange",
    "Line",
    "LineSettings",
    "Priority",
    "RtuOverTcpLine",
    "SerialLine",
    "SlaveHandle",
    "SlaveStats",
    "TcpLine",
    "errors",
]

__version__ = "0.1.0"
