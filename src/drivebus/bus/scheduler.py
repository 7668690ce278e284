"""Bus: one owner task per line, one transaction at a time, highest priority first."""

from __future__ import annotations

import asyncio
import heapq
import itertools
from dataclasses import dataclass, field
from enum import IntEnum
from types import TracebackType
from typing import TYPE_CHECKING

import anyio
import anyio.abc

from drivebus import checks
from drivebus.clock import PreciseTimer, monotonic
from drivebus.errors import (
    ConfigError,
    ConnectionLost,
    FrameError,
    LineClosed,
    LineConfigError,
    ResponseTimeout,
    TransactionError,
    WrongResponder,
)
from drivebus.line.base import Line
from drivebus.pdu import LengthPredictor
from drivebus.settings import LineSettings
from drivebus.tasks import ServiceTasks

if TYPE_CHECKING:
    from drivebus.bus.slave import SlaveHandle

from drivebus.bus.stats import BusStats

__all__ = ["Bus", "Priority"]


class Priority(IntEnum):
    """Request priority on a line: a stop overtakes everything queued."""

    POLL = 0
    CONFIG = 1
    COMMAND = 2
    EMERGENCY = 3


@dataclass(eq=False)
class _Request:
    priority: int
    seq: int
    handle: SlaveHandle
    pdu: bytes
    expect: LengthPredictor | None
    retries_left: int
    future: asyncio.Future[bytes] = field(repr=False)

    def __lt__(self, other: _Request) -> bool:
        if self.priority != other.priority:
            return self.priority > other.priority
        return self.seq < other.seq


_RETRYABLE = (ResponseTimeout, FrameError, WrongResponder)


class Bus:
    """The scheduler of one line: ``async with Bus(line) as bus: bus.slave(3)...``.

    Requests are served highest ``Priority`` first, FIFO within a priority. Reads (and
    writes marked idempotent) are retried after a timeout or a bad frame; a write marked
    non-idempotent never is: the caller must read back state before deciding.
    """

    def __init__(self, line: Line, *, timeout: float = 0.1, retries: int = 2) -> None:
        self.line = line
        self.timeout = checks.response_timeout("response timeout", timeout)
        self.retries = checks.retry_count("retries", retries)
        self.stats = BusStats()
        self._queue: list[_Request] = []
        self._seq = itertools.count()
        self._work: asyncio.Future[None] | None = None
        self._timer = PreciseTimer()
        self._waiting_for: _Request | None = None
        self._in_flight: _Request | None = None
        self._tg: ServiceTasks | None = None
        self._open = False
        self._handles: dict[int, SlaveHandle] = {}

    # -- life cycle ------------------------------------------------------------------------

    async def __aenter__(self) -> Bus:
        await self.line.open()
        self.stats = BusStats()
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

    @property
    def is_open(self) -> bool:
        """True between entering and leaving the ``async with``."""
        return self._open

    def slave(
        self,
        address: int,
        *,
        settings: LineSettings | None = None,
        timeout: float | None = None,
        retries: int | None = None,
        exception_texts: dict[int, str] | None = None,
    ) -> SlaveHandle:
        """A handle for the slave at ``address`` (0 = broadcast) with its own settings."""
        from drivebus.bus.slave import SlaveHandle

        h = SlaveHandle(  # checks address, settings, timeout and retries
            self,
            address,
            settings=settings,
            timeout=self.timeout if timeout is None else timeout,
            retries=self.retries if retries is None else retries,
            exception_texts=exception_texts,
        )
        if h.settings is not None and h.settings != self.line.settings:
            if self.line.settings is None:
                raise ConfigError(
                    f"line {self.line.name} is not a serial line: no per-slave settings"
                )
            if not getattr(self.line, "per_slave_settings", True):
                raise ConfigError(
                    f"slave {h.address}: line {self.line.name} has one setting for all slaves "
                    f"({self.line.settings}); {h.settings} cannot be used on it"
                )
        self._handles[h.address] = h
        return h

    # -- submitting ------------------------------------------------------------------------

    async def execute(
        self,
        handle: SlaveHandle,
        pdu: bytes,
        *,
        expect: LengthPredictor | None,
        priority: Priority,
        idempotent: bool,
    ) -> bytes:
        """Queue one transaction and wait for its reply PDU (empty for a broadcast)."""
        if not self._open:
            raise LineClosed(f"bus on {self.line.name} is not open")
        loop = asyncio.get_running_loop()
        req = _Request(
            int(priority),
            next(self._seq),
            handle,
            pdu,
            expect,
            handle.retries if idempotent and expect is not None else 0,
            loop.create_future(),
        )
        heapq.heappush(self._queue, req)
        self._kick(req)
        reply = await req.future  # cancelling us cancels the future: the owner skips it
        if reply[:1] and reply[0] & 0x80:
            handle.raise_exception(reply)
        return reply

    def _kick(self, req: _Request) -> None:
        if self._work is not None and not self._work.done():
            self._work.set_result(None)
        waiting = self._waiting_for
        if waiting is not None and req < waiting:
            self._timer.wake()  # re-plan: a more urgent request came in during the silence

    def _fail_queued(self, exc: Exception) -> None:
        queue, self._queue = self._queue, []
        if self._in_flight is not None:
            queue.append(self._in_flight)  # cut off mid-transaction: its caller must hear it
        for req in queue:
            if not req.future.done():
                req.future.set_exception(exc)

    # -- the owner task ---------------------------------------------------------------------

    async def _owner(self) -> None:
        loop = asyncio.get_running_loop()
        line = self.line
        try:
            while True:
                if not self._queue:
                    self._work = loop.create_future()
                    await self._work
                    continue
                req = self._queue[0]
                if req.future.done():  # the caller gave up while queued
                    heapq.heappop(self._queue)
                    continue
                ready = line.ready_at(req.handle.settings)
                if ready > monotonic():
                    self._waiting_for = req
                    try:
                        await self._timer.sleep_until(ready)
                    finally:
                        self._waiting_for = None
                    continue  # the queue's head may have changed meanwhile
                heapq.heappop(self._queue)
                self._in_flight = req
                await self._run_one(req)
                self._in_flight = None
        except BaseException as exc:
            self._open = False
            if not isinstance(exc, LineClosed):
                exc = LineClosed(f"bus owner on {self.line.name} stopped: {exc!r}")
            self._fail_queued(exc)
            raise

    async def _run_one(self, req: _Request) -> None:
        h = req.handle
        st = self.stats.slave(h.address)
        try:
            ex = await self.line.transact(
                h.address, req.pdu, expect=req.expect, settings=h.settings, timeout=h.timeout
            )
        except LineClosed as exc:
            if not req.future.done():
                req.future.set_exception(exc)
            raise
        except TransactionError as exc:
            self.stats.transactions += 1
            st.last_error = str(exc)
            if isinstance(exc, ResponseTimeout):
                st.timeouts += 1
            elif isinstance(exc, WrongResponder):
                st.wrong_responder += 1
            elif isinstance(exc, ConnectionLost):
                st.connection_errors += 1
            elif isinstance(exc, LineConfigError):
                pass  # refused before it reached the wire; not a wire error
            else:
                st.crc_errors += 1
            retry = not isinstance(exc, LineConfigError) and not req.future.done()
            if retry and req.retries_left > 0:
                req.retries_left -= 1
                st.retries += 1
                heapq.heappush(self._queue, req)  # same seq: keeps its place in line
            elif not req.future.done():
                req.future.set_exception(exc)
            return
        except (OSError, ValueError) as exc:
            # The port failed under us (unplugged adapter): this request fails, the line is gone.
            err = LineClosed(f"line {self.line.name} failed: {exc}")
            if not req.future.done():
                req.future.set_exception(err)
            raise err from exc
        self.stats.transactions += 1
        self.stats.wire_time += ex.wire_time
        if req.expect is None:
            st.broadcasts += 1
        else:
            st.transactions += 1
            if ex.reply and ex.reply[0] & 0x80:
                st.exceptions += 1
        if not req.future.done():
            req.future.set_result(ex.reply)


