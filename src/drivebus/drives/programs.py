"""What a drive family offers motion programs: buffered and blended moves, speed changes.

A motion program (a queue of moves, a path through waypoints, a speed override) asks of
each drive what its manual allows, and says so where it cannot: a drive that obeys only
stop commands while it moves cannot blend, so a blended move buffers and its plan names
the manual's reason. Each family's profile declares a ``ProgramSupport`` with the
manual's words; the procedures themselves are profile methods (``retarget_absolute``,
``read_completion``).
"""

from __future__ import annotations

from dataclasses import dataclass

__all__ = ["Completion", "ProgramSupport"]


@dataclass(frozen=True)
class ProgramSupport:
    """A family's mechanisms for motion programs; each is the manual's reason, or ""."""

    preload: str = ""
    """Why the next move's target, speed and ramps may be written while a move runs (the
    drive latches them when a move starts), so a buffered move needs only its start
    command once the drive is in position. "": written once the drive is at rest."""
    preload_braking: str = ""
    """Why the next move's values may be written in the last moments of the running move's
    braking (and only when its deceleration is no gentler, so that a stop in that moment
    brakes at least as hard), for a drive that does not latch them. "": not then either."""
    retarget: str = ""
    """How the drive takes a new target (and speed) while it moves: blending, and a speed
    override of a move under way. "": it cannot."""
    no_retarget: str = "its manual documents no way to change the target of a running move"
    """Why it cannot take a new target while it moves (said in a plan that buffers)."""
    jog_speed: str = ""
    """How a running jog (a speed run) takes a new speed without stopping. "": it is
    stopped and started again."""

    @property
    def blends(self) -> bool:
        """True if the drive takes a new target on the fly."""
        return bool(self.retarget)


@dataclass(frozen=True)
class Completion:
    """What a short status read tells of a motion: whether the drive still moves, reports
    the move complete, has an alarm or stands on a limit switch. A buffered move starts
    on it, so it reads as few registers as the drive allows (its full status may take a
    whole poll period on a slow line)."""

    moving: bool
    in_position: bool
    alarm: bool
    limit_positive: bool = False
    limit_negative: bool = False
