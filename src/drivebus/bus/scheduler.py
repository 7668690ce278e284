"""Bus: one owner task per line, one transaction at a time, highest priority first."""

from __future__ import annotations

import asyncio
import functools
import heapq
from asyncio import Future
from collections.abc import AsyncIterator, Callable
from contextlib import asynccontextmanager
from types import TracebackType
from typing import Any

import anyio

from drivebus.bus.masters import heard_foreign
from drivebus.bus.observe import TransactionObserver
from drivebus.bus.owner import Owner
from drivebus.bus.priority import Priority
from drivebus.bus.request import Queued, Request
from drivebus.bus.sent import noted_in
from drivebus.bus.slave import SlaveHandle, handle_on
from drivebus.bus.stats import BusStats
from drivebus.errors import LineClosed, StateError
from drivebus.line.base import Line
from drivebus.pdu import LengthPredictor, ReplyDecoder
from drivebus.settings import LineSettings
from drivebus.tasks import ServiceTasks

__all__ = ["Bus", "Priority", "Queued"]


class Bus(Owner):
    """The scheduler of one line: ``async with Bus(line) as bus: bus.slave(3)...``.

    Requests are served highest ``Priority`` first, FIFO within a priority. Reads (and
    writes marked idempotent) are retried after a timeout or a bad frame; a write marked
    non-idempotent never is: the caller must read back state before deciding.

    A noisy line (bytes nobody asked for keep it from going quiet) fails each request
    with ``LineNoise`` once the request's timeout has passed since it was queued or since
    the noise was noticed, whichever is later; it is not retried, and ``sent`` tells
    whether any attempt went out. Other lines and tasks are unaffected.
    """

    def __init__(self, line: Line, *, timeout: float = 0.1, retries: int = 2) -> None:
        super().__init__(line, timeout=timeout, retries=retries)

    # -- life cycle ------------------------------------------------------------------------

    async def __aenter__(self) -> Bus:
        self._loop = asyncio.get_running_loop()
        self.line.foreign_report = functools.partial(heard_foreign, self)
        await self.line.open()
        self.stats = BusStats()
        self._traced_end = 0.0  # the end of the last traced exchange (its silence for --trace)
        self._open = True
        self._tg = ServiceTasks()
        await self._tg.__aenter__()
        self._tg.start_soon(self._owner, name=f"drivebus bus owner {self.line.name}")
        return self

    async def __aexit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> bool | None:
        self._open = False
        self._fail_queued(LineClosed(f"bus on {self.line.name} closed"))
        assert self._tg is not None
        try:
            return await self._tg.__aexit__(exc_type, exc, tb)
        finally:
            with anyio.CancelScope(shield=True):
                self._timer.close()
                await self.line.close()
                self._drop_chain()

    @property
    def is_open(self) -> bool:
        """True between entering and leaving the ``async with``."""
        return self._open

    def observe(self, observer: TransactionObserver) -> Callable[[], None]:
        """Call ``observer`` with every transaction's outcome from now on (it must be
        quick and must not raise); returns the function that ends it."""
        self._observers.append(observer)

        def end() -> None:
            if observer in self._observers:
                self._observers.remove(observer)

        return end

    def slave(
        self,
        address: int,
        *,
        settings: LineSettings | None = None,
        timeout: float | None = None,
        retries: int | None = None,
        exception_texts: dict[int, str] | None = None,
        guard: float = 0.0,
        frame_timeout: float = 0.0,
    ) -> SlaveHandle:
        """A handle for the slave at ``address`` (0 = broadcast) with its own settings
        (``guard``: extra quiet time before each of its frames, ``frame_timeout``: after
        each of its replies, for bytes it trails; s)."""
        h = handle_on(self, self.line, address, settings=settings,
                      timeout=self.timeout if timeout is None else timeout,
                      retries=self.retries if retries is None else retries,
                      exception_texts=exception_texts, guard=guard,
                      frame_timeout=frame_timeout)
        self._handles[h.address] = h
        return h

    @asynccontextmanager
    async def hold(self) -> AsyncIterator[None]:
        """Keep the line quiet for a burst: enter once the transactions in flight have
        ended; until the body ends only ``Priority.EMERGENCY`` requests go out, the rest
        wait (requests the body queues go first after it, by priority). A group move holds
        its lines so its start commands leave at a known moment, back to back. The body
        itself may await only ``Priority.EMERGENCY`` requests: one below that would wait
        for the hold's end, and is refused (``StateError``, nothing sent)."""
        release = self.hold_now()
        me = asyncio.current_task()
        self._holders[me] = self._holders.get(me, 0) + 1
        try:
            if self._flying:
                waiter = asyncio.get_running_loop().create_future()
                self._idle_waiters.append(waiter)
                await waiter
            yield
        finally:
            if self._holders[me] > 1:
                self._holders[me] -= 1
            else:
                del self._holders[me]
            release()

    def hold_now(self) -> Callable[[], None]:
        """Begin no request below ``Priority.EMERGENCY`` from now on (one waiting for its
        silence goes back to the queue), without waiting for the transaction in flight
        (``hold`` waits for it, on top of this): a stop that must first let another task's
        I/O end keeps the line for itself meanwhile, so nothing else leaves before it.
        Returns the release (idempotent); the stop is queued in the same step as the
        release, ahead of what waited."""
        self._holds += 1
        if any(r.priority < Priority.EMERGENCY for r in self._flying):
            self._withdraw()  # still waiting for its silence: it goes after the holder
        released = False

        def release() -> None:
            nonlocal released
            if not released:
                released = True
                self._holds -= 1
                self._wake_owner()

        return release

    # -- submitting ------------------------------------------------------------------------

    async def execute(
        self,
        handle: SlaveHandle,
        pdu: bytes,
        *,
        expect: LengthPredictor | None,
        priority: Priority,
        idempotent: bool,
        decode: ReplyDecoder | None = None,
    ) -> Any:
        """Queue one transaction and wait for its reply PDU (empty for a broadcast), or
        what ``decode(reply, pdu, handle.address)`` makes of it (a register read's values).
        ``StateError`` at once (nothing sent) for a request below ``Priority.EMERGENCY``
        from inside this task's own ``hold()``: it would wait for the hold's end."""
        if self._holds and priority < Priority.EMERGENCY \
                and asyncio.current_task() in self._holders:
            raise StateError(
                f"slave {handle.address} on {self.line.name}: a request at priority "
                f"{Priority(priority).name} awaited inside this task's own hold() would "
                f"wait for the hold's end: send it at Priority.EMERGENCY, or after the hold")
        req = self._queue_one(handle, pdu, expect, priority, idempotent)
        try:
            reply = await req.future  # cancelling us cancels the future: the owner skips it
        except asyncio.CancelledError:
            await self._cancelled(req)
            raise
        if reply and reply[0] & 0x80:
            if noted_in() is not None:
                self._note(req, "exception")
            handle.raise_exception(reply, pdu)
        if noted_in() is not None:
            self._note(req, "acknowledged")
        return reply if decode is None else decode(reply, pdu, handle.address)

    def queue(
        self,
        handle: SlaveHandle,
        pdu: bytes,
        *,
        expect: LengthPredictor | None,
        priority: Priority,
        idempotent: bool,
    ) -> Queued:
        """Queue one transaction without waiting for it (what a worker process serving
        its lines for another does): its ``future`` gets the reply PDU, an exception reply
        included, or the error; ``retract`` takes it back as a cancelled caller's does."""
        return self._queue_one(handle, pdu, expect, priority, idempotent)

    def _queue_one(self, handle: SlaveHandle, pdu: bytes, expect: LengthPredictor | None,
                   priority: Priority, idempotent: bool) -> Request:
        if not self._open:
            raise LineClosed(f"bus on {self.line.name} is not open")
        req = Request(
            int(priority),
            next(self._seq),
            handle,
            pdu,
            expect,
            handle.retries if idempotent and expect is not None else 0,
            # (the loop's create_future, less its Python frame: two futures per transaction)
            Future(loop=self._loop),
        )
        if self._parked and self._chained is None and not self._flying \
                and self._adopt is None:
            # As the owner does when it wakes from idle (``NoiseWatch.reset``, written out:
            # it runs per transaction).
            noise = self._noise
            noise.seen, noise.since = self.line.last_activity(), None
            # The line is idle: this request (or one more urgent) begins. Nothing else
            # queued, no hold, guard interval or frame timeout to keep: it begins here
            # (``_chain``'s decision for that case, written out), else ``_chain`` decides.
            if self._queue or self._holds or self._trail or handle.guard:
                heapq.heappush(self._queue, req)
                self._chain(True)
            elif not self._begin(req):
                heapq.heappush(self._queue, req)  # it could not begin here: the owner sends it
                self._wake_owner()
        else:
            heapq.heappush(self._queue, req)
            self._kick(req)
        return req

    async def retract(self, req: Queued) -> None:
        """Take back a request of ``queue`` whose caller gave up: withdrawn if its frame
        has not left, else waited for (shielded, bounded) and its outcome reported, as
        for a cancelled ``execute``."""
        assert isinstance(req, Request)
        if not req.future.done():
            req.future.cancel()
        await self._cancelled(req)

    def _kick(self, req: Request) -> None:
        waiting = self._waiting_for
        if waiting is not None and req < waiting:
            # Re-plan: a more urgent request came in during the silence.
            self._timer.wake()
            chained = self._chained is not None
            if self._withdraw() and chained:
                return  # back in the queue: the more urgent one has begun (or the owner woke)
        if self._chained is None:
            self._wake_owner()  # (a chain takes up the queue itself when its transaction ends)
