"""The bus's request: its record while queued and on the wire, and its place in the queue."""

from __future__ import annotations

import asyncio
from dataclasses import dataclass, field
from typing import Protocol

from drivebus.bus.slave import SlaveHandle
from drivebus.clock import monotonic
from drivebus.pdu import LengthPredictor

READS = (b"\x01", b"\x02", b"\x03", b"\x04")
"""The first byte of a read request's PDU (FC01-FC04): a read may always go again."""


class Queued(Protocol):
    """A request of ``Bus.queue``: its future gets the reply PDU or the error."""

    @property
    def future(self) -> asyncio.Future[bytes]:
        """Resolved with the reply PDU (an exception reply included) or the error."""
        ...


@dataclass(eq=False, slots=True)
class Request:
    """One transaction asked of the bus: served highest ``priority`` first, then in the
    order queued (``seq``); it keeps its place when retried or withdrawn."""

    priority: int
    seq: int
    handle: SlaveHandle
    pdu: bytes
    expect: LengthPredictor | None
    retries_left: int
    future: asyncio.Future[bytes] = field(repr=False)
    queued_at: float = field(default_factory=monotonic)
    sent: bool = False
    """An attempt went out on the line (so a device may have acted on it)."""
    outcome: str = ""
    """How its last attempt ended, in words ("acknowledged", "exception 0x02", ...)."""
    landed: asyncio.Future[None] | None = field(default=None, repr=False)
    """Set by a caller cancelled while the request was on the wire: resolved when the
    owner has its outcome."""

    def __lt__(self, other: Request) -> bool:
        if self.priority != other.priority:
            return self.priority > other.priority
        return self.seq < other.seq

