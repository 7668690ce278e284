"""Chained transactions: the line run from its receiver's callbacks, each transaction
begun from the one before (or from the caller that queued onto an idle line)."""

from __future__ import annotations

import asyncio
import heapq

from drivebus.bus.noise import NoiseWatch
from drivebus.bus.outcomes import Outcomes
from drivebus.bus.priority import Priority
from drivebus.bus.request import Request
from drivebus.line.base import Begun, Exchange, Line


class Chains(Outcomes):
    """The scheduler's room for transactions run from callbacks, and for taking back
    the request that waits for its silence (``_withdraw``)."""

    def __init__(self, line: Line, *, timeout: float, retries: int) -> None:
        super().__init__(line, timeout=timeout, retries=retries)
        self._on_reply = self._replied  # one bound method, not one per transaction
        self._chains = line.begins and line.max_in_flight == 1
        """The line runs transactions from callbacks (``Line.begins``): while each goes
        well, the next one begins from the callback that completed the last, or from the
        caller that queued it onto an idle line, and the owner task sleeps."""
        self._chained: tuple[Request, Begun] | None = None
        """The transaction under way from callbacks (``_chain``)."""
        self._adopt: tuple[Request, Begun] | None = None
        """A chained transaction that needs the owner (anything but a sound reply)."""
        self._parked = False
        """The owner waits with nothing to do: a request may begin from its caller."""
        self._chain_trouble_cb = self._chain_trouble

    def _chain(self, fresh: bool = False) -> None:
        """Begin the queue's head from here (the callback that completed the last
        transaction, or the caller that queued onto an idle line) if it needs nothing the
        owner does (a hold, a guard interval, a noisy line); else wake the owner.
        ``fresh``: the noise watch was reset just now (nothing to look at)."""
        queue = self._queue
        while queue:
            req = queue[0]
            if req.future.done():  # its caller gave up while it was queued
                heapq.heappop(queue)
                continue
            if (self._holds and req.priority < Priority.EMERGENCY) or self._trail \
                    or req.handle.guard or not (fresh or self._noise.quiet()):
                break
            heapq.heappop(queue)
            if self._begin(req):
                return
            heapq.heappush(queue, req)  # it could not begin here: the owner sends it
            break
        else:
            # Nothing to do: the owner (waiting while the chain ran) has nothing either,
            # and the next request begins from its caller.
            self._parked = True
            return
        self._wake_owner()

    def _begin(self, req: Request) -> bool:
        """Begin ``req`` on the line from callbacks (it is out of the queue); False if the
        line refused to start it (the owner then sends it itself)."""
        h = req.handle
        self._flying.add(req)
        self._waiting_for = self._replying = req
        self._replying_noise = self._noise
        try:
            begun = self.line.begin(  # type: ignore[attr-defined]  # (positional: per transaction)
                h.address, req.pdu, req.expect, h.settings, h.timeout, None, True,
                self._on_reply)
        except Exception:  # the owner sends it instead, and handles what fails
            self._flying.discard(req)
            self._waiting_for = None
            return False
        if begun.done():
            self._adopt = (req, begun)
            self._wake_owner()
        else:
            self._chained = (req, begun)
            begun.on_done = self._chain_trouble_cb  # (its future, if it needs one)
        return True

    def _chain_trouble(self, fut: asyncio.Future[None]) -> None:
        """The chained transaction ended without a sound reply: the owner takes it up."""
        chained = self._chained
        if chained is None or not chained[1].done() or chained[1].future is not fut:
            return  # (another job's, or one taken back)
        self._chained = None
        if not self._open:
            # The bus is closing (its line lost the job): no owner takes it up, and its
            # caller has heard LineClosed from the close.
            fut.exception()
            return
        self._adopt = chained
        self._wake_owner()

    def _drop_chain(self) -> None:
        """The bus has closed: a chained transaction the owner did not take up is over (its
        caller heard LineClosed); its job's outcome is taken, so none is left unread (one
        still under way is taken by ``_chain_trouble`` when the line fails it)."""
        adopt, self._adopt = self._adopt, None
        if adopt is not None and adopt[1].done():
            adopt[1].future.exception()

    def _withdraw(self) -> bool:
        """Take back the request waiting for its silence (``Line.withdraw``). A chained one
        goes back to the queue at once (same place; dropped if its caller gave up) and the
        queue's head begins, unless a hold or the owner keeps it; one the owner awaits is
        its to put back."""
        if not self.line.withdraw():
            return False
        chained = self._chained
        if chained is not None:
            req, begun = chained
            self._chained = None
            begun.future.exception()  # SendWithdrawn: nothing was sent (its
            # ``_chain_trouble`` finds it no longer chained)
            self._waiting_for = None
            self._landed(req)
            if not req.future.done():
                heapq.heappush(self._queue, req)
            self._chain()
        return True

    def _replied(self, ex: Exchange) -> bool:
        """The line's ``on_reply``: the transaction under way has its exchange. A chained
        one ends here, and the next begins: True, its job's future is left unresolved
        (nobody awaits it; its ``_chain_trouble`` callback goes with it)."""
        req: Request = self._replying  # type: ignore[assignment]  # (set by ``_begin``)
        noise: NoiseWatch = self._replying_noise  # type: ignore[assignment]
        self._replying = self._replying_noise = None
        # A reply's last byte is the line's last activity (a broadcast's silence is more).
        self._succeeded(req, noise, ex, None if req.expect is None else ex.rx_end)
        chained = self._chained
        if chained is not None and chained[0] is req:
            self._chained = self._waiting_for = None
            self._last_end = ex.rx_end
            self._trail = req.handle.frame_timeout
            if req.landed is not None:
                self._settle_landed(req)
            self._flying.discard(req)
            if self._idle_waiters:
                self._landed(req)
            if self._queue:
                self._chain(True)  # (``_succeeded`` reset the noise watch)
            else:
                self._parked = True  # (``_chain`` with nothing queued, written out)
            return True
        return False
