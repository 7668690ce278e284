"""DriveStatus: one common snapshot of any drive's state, decoded by its profile."""

from __future__ import annotations

from dataclasses import dataclass, field

__all__ = ["DriveIdentity", "DriveStatus"]


@dataclass(frozen=True)
class DriveStatus:
    """What a drive reported at one poll; ``raw`` keeps the register words it came from."""

    enabled: bool
    moving: bool
    in_position: bool
    homed: bool
    alarm: bool
    alarm_code: int | None = None
    alarm_text: str = ""
    limit_positive: bool = False
    limit_negative: bool = False
    homing: bool = False
    """A homing procedure is running."""
    homing_error: bool = False
    """The drive reports that a homing failed (CiA 402: statusword bit 13 in homing
    mode): a homing under way ends at once."""
    position: int | None = None
    """Position in pulses (the drive's command or feedback position)."""
    velocity_rpm: float | None = None
    """Motor speed in rev/min, where the drive reports it."""
    raw: dict[str, int] = field(default_factory=dict)
    timestamp: float = 0.0
    """When it was decoded (its reply was in), monotonic s."""
    requested_at: float = 0.0
    """When its first read was queued, monotonic s: its request left no earlier. A
    command is judged only by a status requested after the command's reply came in
    (``SlaveHandle.wrote_at``); 0: not known (a status decoded from given words)."""


@dataclass(frozen=True)
class DriveIdentity:
    """Who the drive says it is, where it can say."""

    family: str
    model: str = ""
    firmware: str = ""
    raw: dict[str, int] = field(default_factory=dict)
