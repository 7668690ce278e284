"""drivebus: Modbus stepper and servo drives on shared RS-485 lines and Modbus TCP, from asyncio.

The public names are imported on first use (``drivebus.lazy``): ``import drivebus`` costs
nothing until a name is used, so a command line tool pays only for what it runs.
"""

from typing import TYPE_CHECKING

from drivebus import errors
from drivebus.lazy import lazy_exports

if TYPE_CHECKING:
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

_HOMES = {
    **dict.fromkeys(["Bus", "BusStats", "Priority", "SlaveHandle", "SlaveStats"],
                    "drivebus.bus"),
    "DriveStatus": "drivebus.drives",
    **dict.fromkeys(["Exchange", "Line", "RtuOverTcpLine", "SerialLine", "TcpLine"],
                    "drivebus.line"),
    **dict.fromkeys(["Axis", "AxisGroup", "AxisState", "Machine", "MotionEvent", "Recording",
                     "open_machine"], "drivebus.motion"),
    "LineSettings": "drivebus.settings",
}

__getattr__, __dir__ = lazy_exports(__name__, _HOMES)

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
