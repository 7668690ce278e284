"""Lines: the media that carry Modbus frames (serial RTU; TCP in ``drivebus.line.tcp``)."""

from drivebus.line.base import Exchange, Line
from drivebus.line.serial import SerialLine
from drivebus.line.tcp import RtuOverTcpLine, TcpLine

__all__ = ["Exchange", "Line", "RtuOverTcpLine", "SerialLine", "TcpLine"]
