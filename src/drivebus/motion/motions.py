"""What an axis keeps of each motion while it runs: the motion itself (``Motion``), a stop
waiting for rest (``RestWait``) and a watcher's mailbox (``Latest``). Plain data with no
I/O, shared by the axis's rooms (``actor``, ``lane``, ``queue``, ``program``, ``jog``) and
read by the judge (``drivebus.motion.judge``)."""

from __future__ import annotations

from collections.abc import Awaitable, Callable
from dataclasses import dataclass, field
from typing import Literal

import anyio

from drivebus.drives.base import HomingSwitches
from drivebus.drives.status import DriveStatus
from drivebus.errors import DrivebusError
from drivebus.motion.envelope import MotionPlan
from drivebus.motion.gate import SegmentGate
from drivebus.motion.handle import BufferMode, QueuePlan, Runs
from drivebus.motion.state import AxisState
from drivebus.motion.trajectory import Trajectory

__all__ = ["Latest", "Motion", "MotionKind", "RestWait"]


MotionKind = Literal["move", "home", "jog"]


@dataclass(eq=False)
class Motion:
    """One motion of the axis, from its submission until the actor decides its outcome."""

    kind: MotionKind
    what: str
    """What it is, for messages: "move to 12.5", "jog at -10", "homing"."""
    prior: AxisState
    """The state before it: where a refused motion leaves the axis."""
    direction: int = 0
    """Drive direction (+1 towards positive pulses, -1, 0 unknown or homing)."""
    start: int | None = None
    target: int | None = None
    """Target in pulses (a move, or a jog bounded by a soft limit)."""
    plan: MotionPlan | None = None
    """Its speed and ramps as the drive gets them (the speed override applied)."""
    base_plan: MotionPlan | None = None
    """Its speed and ramps as asked, before the speed override."""
    speed: float = 0.0
    """A jog's signed speed in user units/s."""
    committing: bool = False
    """The start command was sent or is on its way: the drive may be moving."""
    accepted_at: float | None = None
    """When the drive acknowledged the start; statuses polled later judge the motion."""
    seen_motion: bool = False
    restarting: bool = False
    """A jog being stopped and started again (new speed or direction): rest is no end."""
    switches: HomingSwitches = field(default_factory=HomingSwitches)
    """A homing's limit switches: those it homes on, those where the drive reverses."""
    overrun: float = 0.0
    """How far (pulses) a homing may run on into a switch it reverses at: its braking
    distance and one poll's travel."""
    switch_seen: dict[int, int] = field(default_factory=dict)
    """A homing's reversal switches seen active, by side, with the position first seen."""
    switch_left: set[int] = field(default_factory=set)
    """The reversal switches a homing has reversed away from (met again: a violation)."""
    io: anyio.CancelScope | None = None
    """Its command I/O while that runs: a stop cancels it."""
    io_done: anyio.Event | None = None
    """Set when the command I/O that ``io`` belongs to has ended."""
    finished: anyio.Event = field(default_factory=anyio.Event)
    committed: anyio.Event = field(default_factory=anyio.Event)
    """Set once the drive took its start (``accepted_at``) or its outcome is decided."""
    outcome: BaseException | None = None
    trajectory: Trajectory | None = None
    """Where it will be when (user units, monotonic s), planned once the drive took it."""
    deadline: float | None = None
    """When it has failed if it is not over (MotionTimeout), for a motion nobody awaits."""
    buffer: BufferMode = "aborting"
    runs: Runs = "now"
    reason: str = ""
    """Why it buffers although a blend was asked (the drive, or the geometry)."""
    prepare: Callable[[], Awaitable[None]] | None = None
    """A queued move: write everything but its start (the next ``begin`` starts it)."""
    begin: Callable[[], Awaitable[None]] | None = None
    """A queued motion: its start command (after ``prepare``)."""
    retarget: Callable[[], Awaitable[None]] | None = None
    """A queued move that blends: the new target given on the fly."""
    prepared: bool = False
    blend_speed: float | None = None
    watchdog: float | None = None
    """A queued jog's watchdog period (armed when it starts)."""
    gate: SegmentGate | None = None
    """A group segment: it starts once every axis of the segment before it is there."""
    blend_before_end: float | None = None
    """A blended path corner: the new target reaches the drive this long before the
    motion before it would arrive (None: as that motion begins to brake)."""
    may_reverse: bool = False
    """A path corner may blend although this axis reverses there."""
    ready: Callable[[], Awaitable[None]] | None = None
    """A queued group start: awaited once the move is written, before its start."""
    reports: list[SegmentGate] = field(default_factory=list)
    """Group segments it is part of: told when it is done (or failed)."""
    began: float | None = None
    """When the drive took it (its start or its new target), monotonic s."""
    fresh: anyio.Event | None = None
    """A move a short read found in position: set once a full status polled after that
    was taken in (its handle returns then, with the axis's position up to date)."""
    arrived: tuple[float, float] | None = None
    """When it was seen in position: (the poll before, the poll that saw it)."""
    both_ways: bool = False
    """It goes both ways (a position table): a limit switch either way ends it."""

    def queue_plan(self) -> QueuePlan:
        """How it runs, for its handle."""
        t = self.trajectory
        return QueuePlan(self.buffer, self.runs, self.reason, self.blend_speed,
                         None if t is None else t.start, None if t is None else t.end)

    @property
    def over(self) -> bool:
        """True once its outcome is decided."""
        return self.finished.is_set()

    def finish(self, error: BaseException | None = None) -> None:
        """Decide the outcome (the first decision wins) and cancel its I/O if it runs."""
        if self.finished.is_set():
            return
        self.outcome = error
        self.finished.set()
        self.committed.set()
        if self.io is not None:
            self.io.cancel()


@dataclass(eq=False)
class RestWait:
    """A stop waiting for a status polled after ``after`` that shows the drive at rest."""

    after: float
    event: anyio.Event = field(default_factory=anyio.Event)
    error: DrivebusError | None = None


class Latest:
    """A one-value mailbox: put overwrites, get waits for something new."""

    def __init__(self) -> None:
        self._value: DriveStatus | None = None
        self._event = anyio.Event()

    def put(self, value: DriveStatus) -> None:
        self._value = value
        self._event.set()

    async def get(self) -> DriveStatus:
        await self._event.wait()
        self._event = anyio.Event()
        assert self._value is not None
        return self._value
