"""What a bus tells its observers about each transaction (recordings, dashboards).

An observer is a plain callable the bus calls once per attempt that reached an outcome,
in its owner task or in the line's callback that received the reply. It must be quick
and must not raise: it runs between transactions.
A bus with no observer pays one truth test per transaction.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Literal

__all__ = ["Outcome", "Transaction", "TransactionObserver"]

Outcome = Literal[
    "ok", "exception", "broadcast", "timeout", "crc", "wrong_responder", "connection",
    "noise", "refused",
]
"""How an attempt ended: a reply (``ok``, or a Modbus ``exception`` reply), a broadcast
(no reply by design), or a failure (``refused``: the port would not take the settings,
nothing went on the wire)."""


@dataclass(frozen=True, slots=True)
class Transaction:
    """One attempt on a line, as the bus saw it."""

    slave: int
    function: int
    """The request's Modbus function code."""
    priority: int
    start: float
    """When its request began to leave (monotonic s; for a failure: when it failed)."""
    end: float
    """When its reply's last byte arrived (or the failure was known), monotonic s."""
    wire_time: float
    """Seconds its frames occupied the wire (0 for a failure)."""
    latency: float | None
    """From the request's last byte to the reply's last byte, s (None: no reply)."""
    outcome: Outcome


TransactionObserver = Callable[[Transaction], None]
