"""Buffer modes (PLCopen) and the handle a buffered or blended motion returns.

PLCopen motion function blocks take a ``BufferMode`` that says what a new command does
to the motion under way: ``Aborting`` takes over at once, ``Buffered`` starts when the
motion before it is done (in position), the ``Blending`` modes hand the next target to
the drive before the motion before it ends, so the axis passes through without stopping.
drivebus has ``"aborting"``, ``"buffered"`` and ``"blending"``; a blend is one new target
given on the fly as the motion before it begins to brake, so the axis passes the point
between them at the speed that gives (its plan says how fast: PLCopen's BlendingLow when
the next motion is slower, between BlendingPrevious and BlendingHigh when it is faster).
A drive that cannot take a new target while it moves buffers instead, and the plan says
why (its manual's reason).
"""

from __future__ import annotations

from collections.abc import Awaitable, Callable, Generator
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, Literal, Protocol

import anyio

from drivebus import checks
from drivebus.errors import ArgumentError
from drivebus.tasks import shielded

if TYPE_CHECKING:
    from drivebus.motion.trajectory import Trajectory

__all__ = [
    "BUFFER_MODES",
    "MAX_OVERRIDE",
    "BufferMode",
    "MotionHandle",
    "QueuePlan",
    "check_buffer",
    "check_override",
]

MAX_OVERRIDE = 2.0
"""The largest speed override (200 %, as CNC feed overrides go)."""

BufferMode = Literal["aborting", "buffered", "blending"]
"""What a new motion does to the one under way (PLCopen ``MC_BufferMode``)."""

BUFFER_MODES: tuple[str, ...] = ("aborting", "buffered", "blending")

Runs = Literal["now", "buffered", "blended", "taken over"]


def check_buffer(buffer: object) -> BufferMode:
    """``buffer`` if it is a buffer mode, else ``ArgumentError`` naming the modes."""
    if buffer not in BUFFER_MODES:
        raise ArgumentError(
            f"buffer: {buffer!r} is not a buffer mode ({', '.join(BUFFER_MODES)})")
    return buffer  # type: ignore[return-value]


def check_override(name: str, value: object) -> float:
    """``value`` if it is a speed override (0 < value <= 2), else ``ArgumentError``."""
    v = checks.finite(name, value)
    if not 0 < v <= MAX_OVERRIDE:
        raise ArgumentError(f"{name}: {v:g} is not a speed override (0 < override <= "
                            f"{MAX_OVERRIDE:g})")
    return v


@dataclass(frozen=True)
class QueuePlan:
    """How a motion given with a buffer mode runs, as planned when it was taken."""

    buffer: BufferMode
    """What was asked."""
    runs: Runs
    """``now`` (nothing was under way), ``buffered`` (starts once the motion before it is
    in position), ``blended`` (its target reaches the drive before the motion before it
    brakes) or ``taken over`` (it replaced the motion under way without a stop)."""
    reason: str = ""
    """Why a blend buffers instead (the drive, or the geometry), else ""."""
    blend_speed: float | None = None
    """A blend: the predicted speed (units/s) at which the axis passes the point where the
    motion before it would have stopped."""
    start: float | None = None
    """Predicted (then actual) start, monotonic seconds, once known."""
    arrival: float | None = None
    """Predicted arrival in position, monotonic seconds, once known."""


class _Ticket(Protocol):
    """What a handle needs of the motion behind it."""

    what: str
    finished: anyio.Event
    outcome: BaseException | None
    trajectory: Trajectory | None
    began: float | None
    arrived: tuple[float, float] | None
    fresh: anyio.Event | None

    def queue_plan(self) -> QueuePlan: ...


class MotionHandle:
    """A motion given with a buffer mode: ``await handle`` returns when it is done (or
    raises what ended it); ``await handle.cancel()`` stops the axis and drops every motion
    queued on it. Cancelling a task that awaits the handle stops the axis too (shielded),
    as cancelling ``move_to`` does."""

    def __init__(self, axis: str, ticket: _Ticket, stop: Callable[[], Awaitable[None]]) -> None:
        self.axis = axis
        self._ticket = ticket
        self._stop = stop

    @property
    def what(self) -> str:
        """The motion, for messages ("move to 12.5")."""
        return self._ticket.what

    @property
    def done(self) -> bool:
        """True once its outcome is decided."""
        return self._ticket.finished.is_set()

    @property
    def error(self) -> BaseException | None:
        """What ended it, once done (None: it completed)."""
        return self._ticket.outcome if self.done else None

    @property
    def plan(self) -> QueuePlan:
        """How it runs: buffered, blended (at what speed), and why not blended."""
        return self._ticket.queue_plan()

    @property
    def trajectory(self) -> Trajectory | None:
        """Where the drive is planned to be when (user units, monotonic s), once it took
        the motion (a blend's includes the motion it took over from)."""
        return self._ticket.trajectory

    @property
    def began(self) -> float | None:
        """When the drive took it (its start, or its new target for a blend)."""
        return self._ticket.began

    @property
    def arrived(self) -> tuple[float, float] | None:
        """The polls that bracket its arrival in position: (still on its way, there)."""
        return self._ticket.arrived

    async def ended(self) -> None:
        """Return once it is over, whatever the outcome; cancelling this stops nothing."""
        await self._ticket.finished.wait()

    async def wait(self) -> None:
        """Return when the motion is done; raise what ended it otherwise."""
        try:
            await self._ticket.finished.wait()
            fresh = self._ticket.fresh
            if fresh is not None and self._ticket.outcome is None:
                await fresh.wait()  # a full status after the arrival: positions are current
        except BaseException:
            if not self.done:
                await shielded(self._stop_unless_done)  # (a second cancel cannot cut it)
            raise
        if self._ticket.outcome is not None:
            raise self._ticket.outcome

    async def _stop_unless_done(self) -> None:
        """Stop the axis unless the motion is over by the time this runs (a task of its
        own): of many handles of an axis cancelled together, the first one's stop ends
        the others, which then send none of their own."""
        if not self.done:
            await self._stop()

    def __await__(self) -> Generator[Any, None, None]:
        return self.wait().__await__()

    async def cancel(self) -> None:
        """Stop the axis (decelerating) and drop its queue; returns at rest. Nothing is
        sent if the motion is already over."""
        if not self.done:
            await self._stop()

    def __repr__(self) -> str:
        state = "running" if not self.done else "done" if self.error is None else "failed"
        return f"MotionHandle({self.axis}: {self.what}, {state})"
