"""What an axis tells its listeners: every polled status and its motion events.

A listener is a plain callable that ``Axis.listen`` registers; the axis calls it in the
task that made the decision (its actor, or the commanding task), synchronously: it must
be quick and must not raise. Listening adds no bus traffic: it sees the polls the actor
makes anyway. Recordings (``Machine.record``) are built on it.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Literal

from drivebus.drives.status import DriveStatus

__all__ = ["AxisListener", "MotionEvent", "MotionEventKind"]

MotionEventKind = Literal[
    "accepted", "started", "stop", "in_position", "done", "aborted", "error",
]
"""``accepted``: the axis took a command (checks passed); ``started``: the drive
acknowledged its start command; ``stop``: a stop was requested (by a caller, or by the
actor: a limit, a watchdog, an alarm); ``in_position``: a move's poll showed the drive
there; ``done``: another motion (homing, a jog) ended normally; ``aborted``: a stop ended
a motion; ``error``: a motion failed, or the drive raised an alarm or went offline."""


@dataclass(frozen=True, slots=True)
class MotionEvent:
    """One event of one axis."""

    axis: str
    kind: MotionEventKind
    time: float
    """When it happened (monotonic s); for ``in_position``, when the poll that showed
    it was sent."""
    what: str
    """The motion or command: ``"move to 120"``, ``"homing"``, ``"stop()"``."""
    target: float | None = None
    """The motion's target in user units, where it has one."""
    planned_end: float | None = None
    """``started`` of a move: when its plan brings the drive to the target (monotonic s)."""
    detail: str = ""
    """An error's message, or why a stop was requested."""


AxisListener = Callable[[DriveStatus | MotionEvent], None]
"""Called with each polled ``DriveStatus`` (after the axis took it in: its ``state`` is
the new one) and each ``MotionEvent``."""
