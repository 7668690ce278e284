"""Bus: one owner task per line, one transaction at a time, highest priority first."""

from __future__ import annotations

import asyncio
import heapq
import itertools
import logging
import math
from collections.abc import AsyncIterator, Callable
from contextlib import asynccontextmanager
from dataclasses import dataclass, field
from types import TracebackType

import anyio

from drivebus import checks
from drivebus.bus.observe import Outcome, Transaction, TransactionObserver
from drivebus.bus.priority import Priority
from drivebus.bus.sent import SentRequest, note_sent, noting
from drivebus.bus.slave import SlaveHandle
from drivebus.bus.stats import BusStats
from drivebus.clock import PreciseTimer, monotonic
from drivebus.errors import (
    ConfigError,
    ConnectionLost,
    LineClosed,
    LineConfigError,
    LineNoise,
    ResponseTimeout,
    TransactionError,
    WrongResponder,
)
from drivebus.line.base import Exchange, Line, SendWithdrawn
from drivebus.line.rtu import frame
from drivebus.pdu import LengthPredictor
from drivebus.settings import LineSettings
from drivebus.tasks import ServiceTasks

trace = logging.getLogger("drivebus.trace")
"""Every frame of every bus at DEBUG (``drivebus --trace``): off unless enabled."""

__all__ = ["Bus", "Priority"]

log = logging.getLogger(__name__)

_READS = (b"\x01", b"\x02", b"\x03", b"\x04")
"""The first byte of a read request's PDU (FC01-FC04): a read may always go again."""

_OUTCOME_WAIT = 0.5
"""Beyond its response timeout, how long a cancelled caller waits to learn the outcome
of its request that had already left (then: "outcome unknown"), seconds."""

@dataclass(eq=False)
class _Request:
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

    def __lt__(self, other: _Request) -> bool:
        if self.priority != other.priority:
            return self.priority > other.priority
        return self.seq < other.seq


class _NoiseWatch:
    """Tells the bus owner when bytes nobody asked for keep its line busy, and since when.

    While the owner waits for the line's silence it sends nothing, so if the line's last
    activity moves, bytes arrived that are no reply: noise. From then on each queued
    request has its own timeout to see the line quiet (counted from when it was queued,
    or from when the noise was noticed, whichever is later), never longer.
    """

    def __init__(self, line: Line) -> None:
        self.line = line
        self.seen = line.last_activity()
        self.since: float | None = None
        """When noise was first noticed (None: the line is not known to be noisy)."""

    def reset(self) -> None:
        """The line carried a transaction (or the owner was idle): start watching afresh."""
        self.seen = self.line.last_activity()
        self.since = None

    def look(self, now: float) -> None:
        """Note noise if the line was active since the last look."""
        activity = self.line.last_activity()
        if activity > self.seen:
            self.seen = activity
            if self.since is None:
                self.since = now

    def noted(self, now: float) -> None:
        """The line reported noise itself (a reply lost in it)."""
        if self.since is None:
            self.since = now
        self.seen = self.line.last_activity()

    def deadline(self, req: _Request) -> float | None:
        """The latest time ``req`` may still go out, while the line is noisy."""
        if self.since is None:
            return None
        return max(req.queued_at, self.since) + req.handle.timeout


class Bus:
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
        self.line = line
        self.timeout = checks.response_timeout("response timeout", timeout)
        self.retries = checks.retry_count("retries", retries)
        self.stats = BusStats()
        self._queue: list[_Request] = []
        self._seq = itertools.count()
        self._work: asyncio.Future[None] | None = None
        self._timer = PreciseTimer()
        self._waiting_for: _Request | None = None
        self._flying: set[_Request] = set()
        """Requests whose transaction is under way (at most ``line.max_in_flight``)."""
        self._holds = 0
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

    # -- life cycle ------------------------------------------------------------------------

    async def __aenter__(self) -> Bus:
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

    def _tell(self, req: _Request, outcome: Outcome, ex: Exchange | None = None) -> None:
        """Tell the observers how an attempt of ``req`` ended."""
        if ex is None:
            now = monotonic()
            tx = Transaction(req.handle.address, req.pdu[0] if req.pdu else 0, req.priority,
                             now, now, 0.0, None, outcome)
        else:
            tx = Transaction(req.handle.address, req.pdu[0] if req.pdu else 0, req.priority,
                             ex.tx_start, ex.rx_end, ex.wire_time,
                             None if req.expect is None else ex.rx_end - ex.tx_end, outcome)
        for observer in self._observers:
            observer(tx)

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
        h = SlaveHandle(  # checks address, settings, timeout, retries and guard
            self,
            address,
            settings=settings,
            timeout=self.timeout if timeout is None else timeout,
            retries=self.retries if retries is None else retries,
            exception_texts=exception_texts,
            guard=guard,
            frame_timeout=frame_timeout,
            max_address=max(getattr(self.line, "unit_ids", range(248))),
        )
        if h.settings is not None and h.settings != self.line.settings:
            if self.line.settings is None:
                raise ConfigError(
                    f"line {self.line.name} is not a serial line: no per-slave settings"
                )
            if not self.line.per_slave_settings:
                raise ConfigError(
                    f"slave {h.address}: line {self.line.name} has one setting for all slaves "
                    f"({self.line.settings}); {h.settings} cannot be used on it"
                )
        self._handles[h.address] = h
        return h

    @asynccontextmanager
    async def hold(self) -> AsyncIterator[None]:
        """Keep the line quiet for a burst: enter once the transactions in flight have
        ended; until the body ends only ``Priority.EMERGENCY`` requests go out, the rest
        wait (requests the body queues go first after it, by priority). A group move holds
        its lines so its start commands leave at a known moment, back to back."""
        self._holds += 1
        try:
            if self._flying:
                if any(r.priority < Priority.EMERGENCY for r in self._flying):
                    self.line.withdraw()  # still waiting for its silence: it goes after us
                waiter = asyncio.get_running_loop().create_future()
                self._idle_waiters.append(waiter)
                await waiter
            yield
        finally:
            self._holds -= 1
            self._wake_owner()

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
        try:
            reply = await req.future  # cancelling us cancels the future: the owner skips it
        except asyncio.CancelledError:
            await self._cancelled(req)
            raise
        if noting():
            self._note(req, "exception" if reply[:1] and reply[0] & 0x80 else "acknowledged")
        if reply[:1] and reply[0] & 0x80:
            handle.raise_exception(reply, pdu)
        return reply

    async def _cancelled(self, req: _Request) -> None:
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
        if self.line.withdraw():
            return  # taken back while it waited for its silence: nothing went out
        loop = asyncio.get_running_loop()
        req.landed = loop.create_future()
        with anyio.CancelScope(shield=True), anyio.move_on_after(
                req.handle.timeout + _OUTCOME_WAIT):
            await req.landed
        outcome = (req.outcome or "outcome unknown") if req.landed.done() else \
            "outcome unknown"
        if req.pdu[:1] not in _READS:  # a read that went out changed nothing
            h = req.handle
            log.warning("slave %d on %s: a write (function 0x%02X) was cancelled by its "
                        "caller after it had left: %s", h.address, self.line.name,
                        req.pdu[0] if req.pdu else 0, outcome)
        self._note(req, outcome, cancelled=True)

    def _note(self, req: _Request, outcome: str, *, cancelled: bool = False) -> None:
        """Tell a ``sent_requests`` block that ``req`` reached the wire."""
        note_sent(SentRequest(req.handle.address, req.pdu[0] if req.pdu else 0, req.pdu,
                              outcome, cancelled))

    def _wake_owner(self) -> None:
        if self._work is not None and not self._work.done():
            self._work.set_result(None)

    def _kick(self, req: _Request) -> None:
        self._wake_owner()
        waiting = self._waiting_for
        if waiting is not None and req < waiting:
            # Re-plan: a more urgent request came in during the silence.
            self._timer.wake()
            self.line.withdraw()

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

    # -- the owner task ---------------------------------------------------------------------

    def _landed(self, req: _Request) -> None:
        """``req``'s transaction has ended: once none is in flight, holds may begin."""
        self._flying.discard(req)
        if self._idle_waiters and not self._flying:
            for waiter in self._idle_waiters:
                if not waiter.done():
                    waiter.set_result(None)
            self._idle_waiters.clear()

    async def _owner(self) -> None:
        told = False
        while True:
            try:
                if self.line.max_in_flight > 1:
                    await self._pipeline()
                else:
                    await self._one_at_a_time()
            except BaseException as exc:
                if self._open and _only_cancelled(exc):
                    # Cancelled from outside while the bus is still open: the event loop
                    # is being torn down (asyncio.run's end, a server's force quit). The
                    # stops of the shutdown still need the line: serve on until the bus
                    # is closed by its owner.
                    task = asyncio.current_task()
                    if task is not None:
                        task.uncancel()
                    self._recover_interrupted()
                    if not told:
                        log.warning("bus on %s: its owner task was cancelled from outside "
                                    "(the event loop is shutting down?); it serves on until "
                                    "the bus is closed, so the stops still go out",
                                    self.line.name)
                        told = True
                    continue
                self._open = False
                if not isinstance(exc, LineClosed):
                    exc = LineClosed(f"bus owner on {self.line.name} stopped: {exc!r}")
                self._fail_queued(exc)
                raise

    def _recover_interrupted(self) -> None:
        """After a cancellation from outside cut transactions off (see ``_interrupted``)."""
        for req in list(self._flying):
            self._flying.discard(req)
            self._interrupted(req)
        self._landed_all()
        self._waiting_for = None
        self._work = None

    def _interrupted(self, req: _Request) -> None:
        """``req``'s transaction was cut off by a cancellation from outside: a read (or a
        write that may be retried) goes again; a write that may have left fails, so its
        caller reads back before deciding."""
        req.outcome = "interrupted: it may have reached the drive"
        if not req.future.done():
            if req.pdu[:1] in _READS or req.retries_left > 0:
                heapq.heappush(self._queue, req)
                return
            req.future.set_exception(TransactionError(
                f"slave {req.handle.address}: the transaction was interrupted by a "
                f"cancellation from outside; the request may have reached the drive",
                slave=req.handle.address))
        self._settle_landed(req)

    def _landed_all(self) -> None:
        """Nothing is in flight any more: release the holds that wait for that."""
        if not self._flying:
            for waiter in self._idle_waiters:
                if not waiter.done():
                    waiter.set_result(None)
            self._idle_waiters.clear()

    @staticmethod
    def _settle_landed(req: _Request) -> None:
        """Tell a cancelled caller waiting for ``req``'s outcome that it is known."""
        if req.landed is not None and not req.landed.done():
            req.landed.set_result(None)

    async def _pipeline(self) -> None:
        """Up to ``line.max_in_flight`` transactions at once (a line that keeps no silences
        and matches replies by id): the head of the queue goes out as soon as a slot is
        free. The last slot is kept for ``Priority.EMERGENCY``, so a stop never waits for
        a pipelined poll to come back; a hold lets only those out."""
        loop = asyncio.get_running_loop()
        limit = self.line.max_in_flight
        noise = _NoiseWatch(self.line)
        try:
            await self._dispatch(loop, limit, noise)
        except BaseExceptionGroup as group:
            if len(group.exceptions) == 1:  # one flight failed (the line is gone): say why
                raise group.exceptions[0] from None
            raise

    async def _dispatch(
        self, loop: asyncio.AbstractEventLoop, limit: int, noise: _NoiseWatch
    ) -> None:
        async with anyio.create_task_group() as flights:
            while True:
                if self._queue and self._queue[0].future.done():
                    heapq.heappop(self._queue)  # its caller gave up while it was queued
                    continue
                room = limit - len(self._flying)
                if self._queue:
                    req = self._queue[0]
                    if req.priority < Priority.EMERGENCY:
                        room = 0 if self._holds else room - 1
                    if room > 0:
                        heapq.heappop(self._queue)
                        self._flying.add(req)
                        flights.start_soon(self._fly, req, noise)
                        continue
                self._work = loop.create_future()
                await self._work  # a request, a free slot or the end of a hold

    async def _fly(self, req: _Request, noise: _NoiseWatch) -> None:
        """One pipelined transaction; its slot is free again when it ends."""
        try:
            await self._run_one(req, noise, withdrawable=False)
        except asyncio.CancelledError:
            if self._open:  # cut off from outside: the owner serves on (``_owner``)
                self._interrupted(req)
            raise
        finally:
            self._landed(req)
            self._wake_owner()

    async def _one_at_a_time(self) -> None:
        """One transaction at a time, highest priority first, each after its silence."""
        loop = asyncio.get_running_loop()
        line = self.line
        noise = _NoiseWatch(line)
        while True:
            if not self._queue:
                self._work = loop.create_future()
                await self._work
                noise.reset()
                continue
            req = self._queue[0]
            if req.future.done():  # the caller gave up (or ran out of time) while queued
                heapq.heappop(self._queue)
                continue
            now = monotonic()
            noise.look(now)
            next_expiry = math.inf
            if noise.since is not None:
                next_expiry = self._expire_noisy(noise.since, now)
                if req.future.done():
                    continue
            if self._holds and req.priority < Priority.EMERGENCY:
                self._work = loop.create_future()
                await self._work  # held: only an emergency request or the end of it
                continue
            ready = line.ready_at(req.handle.settings)
            guarded = False
            extra = req.handle.guard + self._trail
            if extra:
                # This slave's guard interval and the frame timeout of the slave that
                # answered last: the owner itself keeps the line quiet that much longer
                # than its silence (since the last traffic) before the frame.
                ready = max(ready, line.last_activity(), self._last_end) + extra
                guarded = ready > now
            # A line that waits for its silence itself gets the request at once and
            # sends it right at the end of the silence; it gives it back if a more
            # urgent one comes, a hold begins or bytes arrive meanwhile. On a line
            # known to be noisy the owner waits itself, watching every deadline.
            deferred = ready > now and line.waits_for_silence and noise.since is None \
                and not guarded
            if ready > now and not deferred:
                self._waiting_for = req
                try:
                    await self._timer.sleep_until(min(ready, next_expiry))
                finally:
                    self._waiting_for = None
                continue  # the queue's head may have changed meanwhile
            heapq.heappop(self._queue)
            self._flying.add(req)
            self._waiting_for = req if deferred else None
            try:
                await self._run_one(req, noise, withdrawable=deferred)
            finally:
                self._waiting_for = None
            self._landed(req)
            if not self._queue:
                # The caller just woken often asks again at once: let it run first (it
                # is scheduled before us), so that its request is found here without
                # a wake-up of its own.
                await asyncio.sleep(0)

    def _expire_noisy(self, since: float, now: float) -> float:
        """Fail the queued requests whose time to see the noisy line quiet has run out;
        return the next such deadline (inf: none)."""
        nearest = math.inf
        for req in self._queue:
            if req.future.done():
                continue
            deadline = max(req.queued_at, since) + req.handle.timeout
            if deadline > now:
                nearest = min(nearest, deadline)
                continue
            h = req.handle
            garbage = (
                f"; {self.line.garbage_bytes} bytes discarded so far"
                if self.line.counts_garbage
                else ""
            )
            exc = LineNoise(
                f"slave {h.address}: {self.line.name} is noisy: bytes nobody asked for kept "
                f"it busy for {(now - since) * 1e3:.0f} ms, past the "
                f"{h.timeout * 1e3:.0f} ms timeout (noise, a babbling device or a slave at "
                f"another rate{garbage}); "
                + ("an earlier attempt was sent" if req.sent else "not sent"),
                slave=h.address,
                line=self.line.name,
                sent=req.sent,
            )
            st = self.stats.slave(h.address)
            st.line_noise += 1
            st.last_error = str(exc)
            req.future.set_exception(exc)
        return nearest

    async def _run_one(self, req: _Request, noise: _NoiseWatch, *, withdrawable: bool) -> None:
        try:
            await self._transact(req, noise, withdrawable=withdrawable)
        finally:
            if req.sent or req.future.done():  # not for a frame taken back before it left
                self._last_end = monotonic()
                self._trail = req.handle.frame_timeout
            if req.landed is not None and req.outcome:
                self._settle_landed(req)

    async def _transact(self, req: _Request, noise: _NoiseWatch, *, withdrawable: bool
                        ) -> None:
        h = req.handle
        st = self.stats.slave(h.address)
        try:
            # Only lines that declare waits_for_silence take the withdrawable keyword.
            extra = {"withdrawable": True} if withdrawable else {}
            ex = await self.line.transact(
                h.address,
                req.pdu,
                expect=req.expect,
                settings=h.settings,
                timeout=h.timeout,
                quiet_by=noise.deadline(req),
                **extra,
            )
        except SendWithdrawn:
            # Taken back before its frame went out: it keeps its place (same seq) and the
            # owner plans again (a more urgent request, a hold, or bytes on the line).
            heapq.heappush(self._queue, req)
            return
        except LineClosed as exc:
            if not req.future.done():
                req.future.set_exception(exc)
            raise
        except LineNoise as exc:
            if trace.isEnabledFor(logging.DEBUG):
                self._trace_failure(req, exc)
            noise.noted(monotonic())
            req.outcome = "no reply (drowned in noise)" if exc.sent else "not sent (noise)"
            if exc.sent:
                self.stats.transactions += 1
            elif req.sent:
                exc = LineNoise(
                    f"{exc} (an earlier attempt was sent)", slave=h.address, line=exc.line
                )
            req.sent = exc.sent
            st.line_noise += 1
            st.last_error = str(exc)
            if self._observers:
                self._tell(req, "noise")
            # Not retried: noise that outlasted the timeout (and, for a drowned reply, the
            # longest frame's wire time) would only hold the caller for another timeout.
            self._retry_or_fail(req, exc, retry=False)
            return
        except TransactionError as exc:
            if trace.isEnabledFor(logging.DEBUG):
                self._trace_failure(req, exc)
            noise.reset()
            req.sent = req.sent or not isinstance(exc, LineConfigError)
            req.outcome = f"failed: {exc}"
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
            if self._observers:
                self._tell(req, _outcome(exc))
            self._retry_or_fail(req, exc, retry=not isinstance(exc, LineConfigError))
            return
        except (OSError, ValueError) as exc:
            # The port failed under us (unplugged adapter): this request fails, the line is gone.
            err = LineClosed(f"line {self.line.name} failed: {exc}")
            if not req.future.done():
                req.future.set_exception(err)
            raise err from exc
        if trace.isEnabledFor(logging.DEBUG):
            self._trace_exchange(req, ex)
        noise.reset()
        req.sent = True
        if req.landed is not None:
            req.outcome = (f"exception 0x{ex.reply[1]:02X}" if ex.reply[:1] and
                           ex.reply[0] & 0x80 and len(ex.reply) > 1 else
                           "no reply (a broadcast)" if req.expect is None else "acknowledged")
        self.stats.transactions += 1
        self.stats.wire_time += ex.wire_time
        outcome: Outcome = "ok"
        if req.expect is None:
            st.broadcasts += 1
            outcome = "broadcast"
        else:
            st.transactions += 1
            self.stats.replies += 1
            self.stats.reply_time += ex.rx_end - ex.tx_end
            st.latency.add(ex.rx_end - ex.tx_end)
            if ex.reply and ex.reply[0] & 0x80:
                st.exceptions += 1
                outcome = "exception"
        if self._observers:
            self._tell(req, outcome, ex)
        if not req.future.done():
            req.future.set_result(ex.reply)

    def _frame_hex(self, unit: int, pdu: bytes) -> str:
        """The bytes of a frame as on the wire (RTU: with its CRC; TCP: unit and PDU)."""
        if self.line.settings is None:
            return f"unit {unit}: {pdu.hex(' ')}"
        return frame(unit, pdu).hex(" ")

    def _trace_exchange(self, req: _Request, ex: Exchange) -> None:
        """Log a completed transaction's request and reply on ``drivebus.trace``."""
        h = req.handle
        at = h.settings or self.line.settings
        fmt = f" {at}" if at is not None else ""
        silence = ""  # on an RTU line, the silence since the previous traced frame ended
        if self._traced_end and self.line.settings is not None:
            silence = f" after {(ex.tx_start - self._traced_end) * 1e3:.3f} ms silence"
        trace.debug("%.6f %s%s tx slave %d%s: %s", ex.tx_start, self.line.name, fmt,
                    h.address, silence, self._frame_hex(h.address, req.pdu))
        if req.expect is None:
            trace.debug("%.6f %s%s -- broadcast, no reply", ex.tx_end, self.line.name, fmt)
        else:
            trace.debug("%.6f %s%s rx slave %d after %.3f ms: %s", ex.rx_end, self.line.name,
                        fmt, h.address, (ex.rx_end - ex.tx_end) * 1e3,
                        self._frame_hex(h.address, ex.reply))
        self._traced_end = ex.rx_end

    def _trace_failure(self, req: _Request, exc: TransactionError) -> None:
        """Log a transaction that failed on ``drivebus.trace``."""
        h = req.handle
        trace.debug("%.6f %s tx slave %d %s: %s: %s", monotonic(), self.line.name, h.address,
                    self._frame_hex(h.address, req.pdu), type(exc).__name__, exc)
        self._traced_end = monotonic()

    def _retry_or_fail(self, req: _Request, exc: TransactionError, *, retry: bool) -> None:
        """Queue ``req`` again if it may be retried and has retries left, else fail it."""
        if req.future.done():
            return  # its caller gave up
        if retry and req.retries_left > 0:
            req.retries_left -= 1
            self.stats.slave(req.handle.address).retries += 1
            heapq.heappush(self._queue, req)  # same seq: keeps its place in line
            self._wake_owner()
        else:
            req.future.set_exception(exc)


def _only_cancelled(exc: BaseException) -> bool:
    """True if ``exc`` is a cancellation, or a group of nothing but cancellations."""
    if isinstance(exc, asyncio.CancelledError):
        return True
    if isinstance(exc, BaseExceptionGroup):
        return all(_only_cancelled(e) for e in exc.exceptions)
    return False


def _outcome(exc: TransactionError) -> Outcome:
    """The observers' name for a failed attempt."""
    if isinstance(exc, ResponseTimeout):
        return "timeout"
    if isinstance(exc, WrongResponder):
        return "wrong_responder"
    if isinstance(exc, ConnectionLost):
        return "connection"
    if isinstance(exc, LineConfigError):
        return "refused"
    return "crc"
