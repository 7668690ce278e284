"""The bus's state: its line, queue, requests in flight, holds and noise watch, and the
bookkeeping every room of the scheduler shares (waking the owner, a transaction's end)."""

from __future__ import annotations

import asyncio
import itertools
import logging

from drivebus import checks
from drivebus.bus.noise import NoiseWatch
from drivebus.bus.observe import TransactionObserver
from drivebus.bus.request import Request
from drivebus.bus.slave import SlaveHandle
from drivebus.bus.stats import BusStats
from drivebus.clock import PreciseTimer, monotonic
from drivebus.line.base import Line
from drivebus.tasks import ServiceTasks

log = logging.getLogger("drivebus.bus.scheduler")
"""The bus's log (one name for all the scheduler's rooms)."""

trace = logging.getLogger("drivebus.trace")
"""Every frame of every bus at DEBUG (``drivebus --trace``): off unless enabled."""


class BusState:
    """What the scheduler of one line knows; its rooms (``outcomes``, ``chain``,
    ``transaction``, ``cancel``, ``owner``) add what it does, ``Bus`` is them all."""

    def __init__(self, line: Line, *, timeout: float, retries: int) -> None:
        self.line = line
        self.timeout = checks.response_timeout("response timeout", timeout)
        self.retries = checks.retry_count("retries", retries)
        self.stats = BusStats()
        self._queue: list[Request] = []
        self._loop: asyncio.AbstractEventLoop | None = None
        """The event loop the bus runs in (set when it opens)."""
        self._seq = itertools.count()
        self._work: asyncio.Future[None] | None = None
        self._timer = PreciseTimer()
        self._waiting_for: Request | None = None
        self._flying: set[Request] = set()
        """Requests whose transaction is under way (at most ``line.max_in_flight``)."""
        self._holds = 0
        self._holders: dict[asyncio.Task[object] | None, int] = {}
        """The tasks inside ``hold()``, with how many holds each has entered."""
        self._idle_waiters: list[asyncio.Future[None]] = []
        self._tg: ServiceTasks | None = None
        self._open = False
        self._handles: dict[int, SlaveHandle] = {}
        self._observers: list[TransactionObserver] = []
        self._last_end = 0.0
        """When the last transaction ended (monotonic), for guard intervals on lines that
        keep no silences of their own."""
        self._trail = 0.0
        """The frame timeout of the slave of the last transaction (s)."""
        self._replying: Request | None = None
        """The request whose exchange the line's ``on_reply`` (``_replied``) will bring."""
        self._replying_noise: NoiseWatch | None = None
        self._noise = NoiseWatch(line)
        """The one-at-a-time owner's watch for noise (shared with the chained sends)."""

    def _wake_owner(self) -> None:
        if self._work is not None and not self._work.done():
            self._work.set_result(None)

    def _ended(self, req: Request) -> None:
        """``req``'s transaction is over (not withdrawn): what the next one keeps to."""
        if req.sent or req.future.done():  # not for a frame taken back before it left
            self._last_end = monotonic()
            self._trail = req.handle.frame_timeout
        if req.landed is not None and req.outcome:
            self._settle_landed(req)

    def _fail_queued(self, exc: Exception) -> None:
        queue, self._queue = self._queue, []
        queue.extend(self._flying)  # cut off mid-transaction: their callers must hear it
        for waiter in self._idle_waiters:
            if not waiter.done():
                waiter.set_exception(exc)
        self._idle_waiters.clear()
        for req in queue:
            if not req.future.done():
                req.future.set_exception(exc)

    def _landed(self, req: Request) -> None:
        """``req``'s transaction has ended: once none is in flight, holds may begin."""
        self._flying.discard(req)
        if self._idle_waiters and not self._flying:
            for waiter in self._idle_waiters:
                if not waiter.done():
                    waiter.set_result(None)
            self._idle_waiters.clear()

    def _landed_all(self) -> None:
        """Nothing is in flight any more: release the holds that wait for that."""
        if not self._flying:
            for waiter in self._idle_waiters:
                if not waiter.done():
                    waiter.set_result(None)
            self._idle_waiters.clear()

    @staticmethod
    def _settle_landed(req: Request) -> None:
        """Tell a cancelled caller waiting for ``req``'s outcome that it is known."""
        if req.landed is not None and not req.landed.done():
            req.landed.set_result(None)
