"""Request priorities on a line."""

from __future__ import annotations

from enum import IntEnum

__all__ = ["Priority"]


class Priority(IntEnum):
    """Request priority on a line: a stop overtakes everything queued."""

    POLL = 0
    CONFIG = 1
    COMMAND = 2
    EMERGENCY = 3
