"""The baud rate a serial port really runs, as the kernel reports it (Linux termios2).

A driver that cannot generate a requested rate may substitute another one (the nearest it
can make, or a fallback) and report that; reading it back tells a port that runs the line
as asked from one that would talk to the drives at the wrong rate.
"""

from __future__ import annotations

import array
import fcntl

__all__ = ["port_baudrate", "rate_matches"]

try:
    from serial.serialposix import TCGETS2  # type: ignore[attr-defined]
except ImportError:  # not Linux: no termios2
    TCGETS2 = None

_C_OSPEED = 10
"""Index of ``c_ospeed`` in ``struct termios2`` read as ints (as pyserial does)."""

TOLERANCE = 0.02
"""Largest relative baud-rate error a UART link tolerates (both ends add theirs)."""


def port_baudrate(fd: int) -> int | None:
    """The output baud rate the port behind ``fd`` runs, or None if it cannot be read."""
    if TCGETS2 is None:
        return None
    buf = array.array("i", [0] * 64)
    try:
        fcntl.ioctl(fd, TCGETS2, buf)
    except OSError:
        return None
    return buf[_C_OSPEED] or None


def rate_matches(wanted: int, actual: int | None) -> bool:
    """True if ``actual`` (None: unknown) is within ``TOLERANCE`` of ``wanted``."""
    return actual is None or abs(actual - wanted) <= TOLERANCE * wanted
