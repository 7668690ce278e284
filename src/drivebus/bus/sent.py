"""What reached the wire: a caller that must account for every write (a parameter load,
a commissioning step) asks the bus to note each request of its own that went out, even
one whose caller was cancelled after its frame had left.

``with sent_requests() as sent:`` notes, in ``sent``, every request the current task (and
the tasks it starts) made that reached the wire while the block runs, with its outcome. A
request withdrawn before its first byte is not there: it never reached a drive.
"""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager
from contextvars import ContextVar
from dataclasses import dataclass

__all__ = ["SentRequest", "note_sent", "sent_requests"]


@dataclass(frozen=True, slots=True)
class SentRequest:
    """One request that went out on a line."""

    slave: int
    function: int
    """Its Modbus function code."""
    pdu: bytes
    outcome: str
    """"acknowledged", "exception 0xNN", or what is known of it ("no reply", "outcome
    unknown: its caller was cancelled while it was on the wire")."""
    cancelled: bool = False
    """Its caller was cancelled after the frame had left."""


_SENT: ContextVar[list[SentRequest] | None] = ContextVar("drivebus_sent_requests",
                                                         default=None)


@contextmanager
def sent_requests() -> Iterator[list[SentRequest]]:
    """Note the requests that reach the wire while the block runs (see the module)."""
    noted: list[SentRequest] = []
    token = _SENT.set(noted)
    try:
        yield noted
    finally:
        _SENT.reset(token)


def note_sent(request: SentRequest) -> None:
    """Tell the ``sent_requests`` block the caller runs in, if any."""
    noted = _SENT.get()
    if noted is not None:
        noted.append(request)


noted_in = _SENT.get
"""The list of the ``sent_requests`` block the caller runs in, None outside one (one
call into C: it is asked per transaction)."""
