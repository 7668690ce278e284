"""A caller that gives up, and a transaction cut off from outside: the request withdrawn
before its frame leaves, or waited for and its outcome reported, or sent again."""

from __future__ import annotations

import asyncio
import heapq

import anyio

from drivebus.bus.chain import Chains
from drivebus.bus.request import READS, Request
from drivebus.bus.state import log
from drivebus.errors import TransactionError

OUTCOME_WAIT = 0.5
"""Beyond its response timeout, how long a cancelled caller waits to learn the outcome
of its request that had already left (then: "outcome unknown"), seconds."""


class Cancellations(Chains):
    """The scheduler's room for cancelled callers and interrupted transactions."""

    async def _cancelled(self, req: Request) -> None:
        """The caller of ``req`` was cancelled: take the request back if its frame has not
        left (nothing reaches the drive), else wait (shielded, bounded) for its outcome
        and report it: in the log and to a ``sent_requests`` block."""
        if req.future.done() and not req.future.cancelled():
            self._note(req, "acknowledged" if req.future.exception() is None
                       else f"failed: {req.future.exception()}", cancelled=True)
            return  # it had ended: the cancellation came with its reply
        if req not in self._flying:
            if req.sent:  # an earlier attempt went out; the retry is dropped
                self._note(req, f"{req.outcome}; its retry was dropped", cancelled=True)
            return  # still queued: the owner drops it, nothing goes out
        if self._withdraw():
            return  # taken back while it waited for its silence: nothing went out
        loop = asyncio.get_running_loop()
        req.landed = loop.create_future()
        with anyio.CancelScope(shield=True), anyio.move_on_after(
                req.handle.timeout + OUTCOME_WAIT):
            await req.landed
        outcome = (req.outcome or "outcome unknown") if req.landed.done() else \
            "outcome unknown"
        if req.pdu[:1] not in READS:  # a read that went out changed nothing
            h = req.handle
            log.warning("slave %d on %s: a write (function 0x%02X) was cancelled by its "
                        "caller after it had left: %s", h.address, self.line.name,
                        req.pdu[0] if req.pdu else 0, outcome)
        self._note(req, outcome, cancelled=True)

    def _recover_interrupted(self) -> None:
        """After a cancellation from outside cut transactions off (see ``_interrupted``)."""
        for req in list(self._flying):
            if self._chained is not None and req is self._chained[0]:
                continue  # run from callbacks: not cut off
            self._flying.discard(req)
            self._interrupted(req)
        self._landed_all()
        self._waiting_for = None
        self._work = None

    def _interrupted(self, req: Request) -> None:
        """``req``'s transaction was cut off by a cancellation from outside: a read (or a
        write that may be retried) goes again; a write that may have left fails, so its
        caller reads back before deciding."""
        req.outcome = "interrupted: it may have reached the drive"
        if not req.future.done():
            if req.pdu[:1] in READS or req.retries_left > 0:
                heapq.heappush(self._queue, req)
                return
            req.future.set_exception(TransactionError(
                f"slave {req.handle.address}: the transaction was interrupted by a "
                f"cancellation from outside; the request may have reached the drive",
                slave=req.handle.address))
        self._settle_landed(req)
