"""The machine's side of its worker processes: a bus per line that a worker serves.

A ``RemoteBus`` is what the axes, the application layer and the front ends see of a line
served by a worker: ``Bus``'s ``slave``, ``execute``, ``hold``, ``observe``, ``stats`` and
``line``. Each transaction crosses to the worker and its reply or typed error comes back;
a caller cancelled meanwhile has its request taken back there if its frame has not left,
else waits (shielded, bounded) for its outcome, as with a bus of its own process.

A worker that dies fails what it had in hand with ``ConnectionLost`` (a transaction
error: the axes' polls count it), tells the machine at once (``on_lost``: its axes go
Offline) and is started again; while it is away its lines' requests fail at once. If it
cannot be started again, its lines stay failed and the log says why. A worker that hangs
(stopped, deadlocked: its lines' stops cannot leave) is one the machine has not heard
from for ``WATCHDOG`` seconds (a serving worker says it is alive five times a second): it
is killed, and goes the same way.
"""

from __future__ import annotations

import asyncio
import collections
import contextlib
import itertools
import logging
import os
import socket
import subprocess
import sys
import weakref
from collections.abc import AsyncIterator, Callable, Sequence
from dataclasses import dataclass
from typing import Any

import anyio
import anyio.lowlevel

import drivebus.motion.workers.protocol as p
from drivebus import checks
from drivebus.bus import BusStats, Priority, SlaveHandle, Transaction, TransactionObserver
from drivebus.bus.sent import SentRequest, note_sent, noted_in
from drivebus.bus.slave import handle_on
from drivebus.clock import monotonic
from drivebus.config import LineConfig
from drivebus.errors import ConnectionLost, DrivebusError, LineClosed
from drivebus.line.base import Line
from drivebus.pdu import LengthPredictor, ReplyDecoder, response_length
from drivebus.settings import LineSettings
from drivebus.tasks import ServiceTasks

__all__ = ["LineSpec", "RemoteBus", "RemoteLine", "WorkerPool"]

log = logging.getLogger(__name__)

START_TIMEOUT = 30.0
"""How long a worker may take to start and open its lines, seconds."""
CLOSE_TIMEOUT = 10.0
"""How long a worker may take to close its lines and end, seconds."""
RESTARTS = 3
"""How often a worker that died is started again before its lines are given up."""
_OUTCOME_WAIT = 1.5
"""Beyond its response timeout, how long a cancelled caller waits for the worker to say
what became of its request (the bus's own wait, and the way there and back), seconds."""


def _nothing() -> None:
    """A release with nothing to release."""


@dataclass(frozen=True)
class LineSpec:
    """One line a worker serves: its name, the config it opens, its bus's settings."""

    name: str
    config: LineConfig
    timeout: float
    retries: int


class RemoteLine:
    """What the machine knows of a line a worker serves: the name, settings and
    capabilities of the (unopened) ``Line`` made from its config, and the garbage count
    the worker reports."""

    def __init__(self, line: Line) -> None:
        self._line = line
        self.name = line.name
        self.settings: LineSettings | None = line.settings
        self.per_slave_settings = line.per_slave_settings
        self.max_in_flight = line.max_in_flight
        self.counts_garbage = line.counts_garbage
        self.garbage_bytes = 0
        """Bytes received outside any reply, as of the worker's last report."""

    def __getattr__(self, name: str) -> Any:
        if name.startswith("_"):
            raise AttributeError(name)
        return getattr(self._line, name)

    def __repr__(self) -> str:
        return f"RemoteLine({self._line!r})"


class RemoteBus:
    """A line served by a worker process, with the interface of ``Bus`` the rest of the
    machine uses. ``stats`` are the worker's, as of its last report (at most
    ``serve.STATS_PERIOD`` old)."""

    def __init__(self, worker: _Worker, index: int, line: Line, *, timeout: float,
                 retries: int) -> None:
        self.line = RemoteLine(line)
        self.timeout = checks.response_timeout("response timeout", timeout)
        self.retries = checks.retry_count("retries", retries)
        self.stats = BusStats()
        self._earlier: BusStats | None = None
        """The line's counters when its last worker died (None: none has): the next one's
        go on from them (``BusStats.after``)."""
        self.stops_taken: collections.deque[float] = collections.deque(maxlen=16)
        """When the worker queued the last emergency requests (stops) on this line
        (``time.monotonic``, the host's clock): from there on a stop is the worker's to
        schedule; before, it was crossing between the processes."""
        self._worker = worker
        self._index = index
        self._handles: weakref.WeakKeyDictionary[SlaveHandle, tuple[int, tuple[Any, ...]]] = \
            weakref.WeakKeyDictionary()
        self._observers: list[TransactionObserver] = []
        self._open = True

    @property
    def is_open(self) -> bool:
        """True until the machine closes its workers."""
        return self._open

    @property
    def worker_pid(self) -> int | None:
        """The process id of the worker serving the line (None while it is away)."""
        return self._worker.pid

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
        """A handle for the slave at ``address``, as ``Bus.slave`` makes it."""
        return handle_on(self, self.line, address, settings=settings,
                         timeout=self.timeout if timeout is None else timeout,
                         retries=self.retries if retries is None else retries,
                         exception_texts=exception_texts, guard=guard,
                         frame_timeout=frame_timeout)

    def _hid(self, handle: SlaveHandle) -> int:
        """The worker's number for ``handle``, its settings sent where they changed."""
        params = (handle.address, handle.settings, handle.timeout, handle.retries,
                  handle.guard, handle.frame_timeout)
        known = self._handles.get(handle)
        if known is not None and known[1] == params and known[0] in self._worker.handles:
            return known[0]
        hid = known[0] if known is not None else next(self._worker.ids)
        if known is None:
            weakref.finalize(handle, self._worker.forget, hid)
        self._handles[handle] = (hid, params)
        self._worker.handles.add(hid)
        self._worker.send((p.HANDLE, hid, self._index, *params))
        return hid

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
        """Have the worker run one transaction; its reply PDU (empty for a broadcast), or
        what ``decode`` makes of it (``Bus.execute``)."""
        w = self._worker
        if not self._open:
            raise LineClosed(f"bus on {self.line.name} is not open")
        if w.down is not None:
            raise ConnectionLost(str(w.down), slave=handle.address)
        hid = self._hid(handle)
        rid, fut = w.request(hid, pdu, expect, int(priority), idempotent)
        try:
            reply = await fut
        except asyncio.CancelledError:
            await w.retract(rid, fut, handle, pdu)
            raise
        if noted_in() is not None:
            note_sent(SentRequest(handle.address, pdu[0] if pdu else 0, pdu,
                                  "exception" if reply[:1] and reply[0] & 0x80
                                  else "acknowledged"))
        if reply[:1] and reply[0] & 0x80:
            handle.raise_exception(reply)
        return reply if decode is None else decode(reply, pdu, handle.address)

    @contextlib.asynccontextmanager
    async def hold(self) -> AsyncIterator[None]:
        """``Bus.hold`` in the worker: entered once its transactions in flight ended; until
        the body ends only ``Priority.EMERGENCY`` requests go out."""
        w = self._worker
        if w.down is not None:
            yield  # nothing goes out on it anyway
            return
        hid = next(w.ids)
        held: asyncio.Future[Any] = asyncio.get_running_loop().create_future()
        w.holds[hid] = held
        w.send((p.HOLD, hid, self._index))
        try:
            error = await held
            if error is not None:
                raise p.decode_error(error)
            yield
        finally:
            w.holds.pop(hid, None)
            w.send((p.UNHOLD, hid))

    def hold_now(self) -> Callable[[], None]:
        """``Bus.hold_now`` in the worker: from when it takes this (before any request
        sent after it) it begins nothing below ``Priority.EMERGENCY`` until the release
        (idempotent) reaches it."""
        w = self._worker
        if w.down is not None:
            return _nothing  # nothing goes out on it anyway
        hid = next(w.ids)
        w.send((p.HOLD_NOW, hid, self._index))
        released = False

        def release() -> None:
            nonlocal released
            if not released:
                released = True
                if w.down is None:
                    w.send((p.UNHOLD, hid))

        return release

    def observe(self, observer: TransactionObserver) -> Callable[[], None]:
        """Call ``observer`` with every transaction's outcome from now on (from the
        worker's reports); returns the function that ends it."""
        self._observers.append(observer)
        if len(self._observers) == 1:
            self._worker.send((p.OBSERVE, self._index, True))

        def end() -> None:
            if observer in self._observers:
                self._observers.remove(observer)
                if not self._observers:
                    self._worker.send((p.OBSERVE, self._index, False))

        return end

    def _seen(self, txs: Sequence[Transaction]) -> None:
        for tx in txs:
            for observer in list(self._observers):
                observer(tx)

    def _reattached(self) -> None:
        """A new worker serves the line: it knows no handles and observes nothing yet."""
        self._handles = weakref.WeakKeyDictionary()
        if self._observers:
            self._worker.send((p.OBSERVE, self._index, True))

    def __repr__(self) -> str:
        return f"RemoteBus({self.line.name!r}, worker pid {self._worker.pid})"


class _Worker:
    """One worker process and the machine's end of its socket."""

    def __init__(self, number: int, specs: Sequence[LineSpec], lines: Sequence[Line],
                 pool: WorkerPool) -> None:
        self.number = number
        self.specs = list(specs)
        self.pool = pool
        self.buses = [RemoteBus(self, i, line, timeout=s.timeout, retries=s.retries)
                      for i, (s, line) in enumerate(zip(specs, lines, strict=True))]
        self.ids = itertools.count(1)
        self.handles: set[int] = set()
        self.expects: dict[Any, int] = {response_length: 0, None: 1}
        self.pending: dict[int, asyncio.Future[bytes]] = {}
        self.late: dict[int, str] = {}
        """Outcomes of requests whose caller was cancelled (for ``retract``)."""
        self.cancels: dict[int, asyncio.Future[tuple[SentRequest | None, bool]]] = {}
        self.holds: dict[int, asyncio.Future[Any]] = {}
        self.down: ConnectionLost | None = None
        """Why the worker is away (None while it serves)."""
        self.restarts = 0
        self.proc: subprocess.Popen[bytes] | None = None
        self.channel: p.Channel | None = None
        self.loop: asyncio.AbstractEventLoop | None = None
        self.heard = 0.0
        """When the worker's last message came (monotonic s): the watchdog's measure."""
        self._silent: float | None = None
        """How long the worker was silent when the watchdog killed it (None: it was not)."""
        self._ready: asyncio.Future[Any] | None = None
        self._closed: asyncio.Future[None] | None = None
        self._closing = False

    @property
    def pid(self) -> int | None:
        return None if self.proc is None or self.down is not None else self.proc.pid

    @property
    def names(self) -> list[str]:
        return [s.name for s in self.specs]

    def send(self, message: tuple[Any, ...], *, now: bool = False) -> None:
        """Send ``message`` to the worker, at the end of this loop turn (``now``: at once)."""
        if self.channel is not None:
            if now:
                self.channel.send_now(message)
            else:
                self.channel.send(message)

    def forget(self, hid: int) -> None:
        """Handle ``hid`` is gone (its finalizer: in whatever thread the collector ran)."""
        loop = self.loop
        if loop is None or loop.is_closed():
            return  # no loop any more: no worker either
        try:
            running = asyncio.get_running_loop()
        except RuntimeError:
            running = None
        if running is loop:
            self._forget(hid)
        else:  # another thread: the socket and the handle set are the loop's alone
            with contextlib.suppress(RuntimeError):  # closed meanwhile
                loop.call_soon_threadsafe(self._forget, hid)

    def _forget(self, hid: int) -> None:
        if hid in self.handles:
            self.handles.discard(hid)
            self.send((p.FORGET, hid))

    @property
    def serving(self) -> bool:
        """Whether the worker is up and serving its lines (what the watchdog watches)."""
        return (self.down is None and self.channel is not None and not self._closing
                and self._ready is not None and self._ready.done())

    def hung(self, silent: float) -> None:
        """The worker said nothing for ``silent`` seconds: kill it (its socket then closes,
        and ``on_lost`` fails what it had in hand and has it started again)."""
        self._silent = silent
        log.error("worker %d for line %s said nothing for %.1f s: taken for hung, killed",
                  self.number, ", ".join(self.names), silent)
        if self.proc is not None:
            with contextlib.suppress(OSError):
                self.proc.kill()
        if self.channel is not None and self.channel.transport is not None:
            self.channel.transport.abort()

    def request(self, hid: int, pdu: bytes, expect: LengthPredictor | None, priority: int,
                idempotent: bool) -> tuple[int, asyncio.Future[bytes]]:
        token = self.expects.get(expect)
        if token is None:
            token = self.expects[expect] = len(self.expects)
            self.send((p.EXPECT, token, expect))
        rid = next(self.ids)
        fut: asyncio.Future[bytes] = asyncio.get_running_loop().create_future()
        self.pending[rid] = fut
        # a stop leaves at once: it does not wait for the rest of this loop turn
        self.send((p.TX, rid, hid, pdu, token, priority, idempotent),
                  now=priority >= Priority.EMERGENCY)
        return rid, fut

    async def retract(self, rid: int, fut: asyncio.Future[bytes], handle: SlaveHandle,
                      pdu: bytes) -> None:
        """The caller of request ``rid`` was cancelled: have the worker take it back (or
        learn its outcome) and tell a ``sent_requests`` block what reached the wire."""
        outcome: tuple[SentRequest | None, bool] | None = None
        if self.down is None and rid in self.pending:
            answer: asyncio.Future[tuple[SentRequest | None, bool]] = \
                asyncio.get_running_loop().create_future()
            self.cancels[rid] = answer
            self.send((p.CANCEL, rid))
            with anyio.CancelScope(shield=True), \
                    anyio.move_on_after(handle.timeout + _OUTCOME_WAIT):
                outcome = await answer
            self.cancels.pop(rid, None)
        late = self.late.pop(rid, None)
        self.pending.pop(rid, None)
        if outcome is not None and outcome[0] is not None:
            note_sent(outcome[0])
        elif late is not None:
            note_sent(SentRequest(handle.address, pdu[0] if pdu else 0, pdu, late, True))

    # -- messages from the worker ---------------------------------------------------------------

    def on_message(self, m: tuple[Any, ...]) -> None:
        self.heard = monotonic()
        tag = m[0]
        if tag == p.OK or tag == p.ERR:
            fut = self.pending.get(m[1])
            if fut is None:
                return
            if fut.done():  # its caller was cancelled: ``retract`` reports what came
                self.late[m[1]] = ("acknowledged" if tag == p.OK
                                   else f"failed: {p.decode_error(m[2])}")
                return
            del self.pending[m[1]]
            if tag == p.OK:
                fut.set_result(m[2])
            else:
                fut.set_exception(p.decode_error(m[2]))
        elif tag == p.TAKEN:
            self.buses[m[1]].stops_taken.append(m[2])
        elif tag == p.STATS:
            bus = self.buses[m[1]]
            bus.stats = m[2] if bus._earlier is None else m[2].after(bus._earlier)
            bus.line.garbage_bytes = m[3]
        elif tag == p.SEEN:
            self.buses[m[1]]._seen(m[2])
        elif tag == p.HELD:
            held = self.holds.get(m[1])
            if held is not None and not held.done():
                held.set_result(m[2])
        elif tag == p.CANCELLED:
            answer = self.cancels.get(m[1])
            if answer is not None and not answer.done():
                answer.set_result((m[2], m[3]))
        elif tag == p.LOG:
            logging.getLogger(m[1]).log(m[2], "%s", m[3])
        elif tag == p.READY:
            if self._ready is not None and not self._ready.done():
                self._ready.set_result(m[1])
        elif tag == p.CLOSED and self._closed is not None and not self._closed.done():
            self._closed.set_result(None)

    def on_lost(self, exc: BaseException | None) -> None:
        self.channel = None
        if self._ready is not None and not self._ready.done():
            self._ready.set_exception(ConnectionLost(f"worker {self.number} ended before it "
                                                     f"was ready"))
        if self._closed is not None and not self._closed.done():
            self._closed.set_result(None)
        if self._closing:
            self._fail(LineClosed(f"bus on {', '.join(self.names)} closed"))
            return
        code = self.proc.poll() if self.proc is not None else None
        why = f"exit code {code}" if code is not None else (str(exc) if exc else "no answer")
        if self._silent is not None:
            why = f"silent for {self._silent:.1f} s: killed as hung"
            self._silent = None
        for bus in self.buses:  # the next worker's counters go on from these
            bus._earlier = bus.stats
        self.down = ConnectionLost(
            f"the worker process serving line {', '.join(self.names)} died ({why})")
        log.error("%s: its axes are Offline; starting it again", self.down)
        self._fail(self.down)
        self.pool.lost(self)

    def _fail(self, exc: DrivebusError) -> None:
        """Everything the worker had in hand fails with ``exc``."""
        pending, self.pending = self.pending, {}
        for rid, fut in pending.items():
            if not fut.done():
                fut.set_exception(type(exc)(str(exc)))
            else:
                self.late.setdefault(rid, "outcome unknown: the worker serving the line died")
        for answer in self.cancels.values():
            if not answer.done():
                answer.set_result((None, False))
        for held in self.holds.values():
            if not held.done():
                held.set_result(None)  # nothing goes out: the hold holds trivially
        self.handles.clear()

    # -- life --------------------------------------------------------------------------------

    async def start(self) -> None:
        """Start the process, have it open its lines; ``DrivebusError`` if it cannot."""
        loop = self.loop = asyncio.get_running_loop()
        ours, theirs = socket.socketpair(socket.AF_UNIX, socket.SOCK_STREAM)
        try:  # a fork and exec, once per worker: quick enough to do in the loop
            self.proc = subprocess.Popen(  # noqa: ASYNC220
                [sys.executable, "-m", "drivebus.motion.workers.serve", str(theirs.fileno())],
                pass_fds=(theirs.fileno(),), stdin=subprocess.DEVNULL)
        except OSError as exc:
            ours.close()
            raise DrivebusError(f"cannot start a worker process: {exc}") from exc
        finally:
            theirs.close()
        self._ready = loop.create_future()
        self._closing = False
        self.expects = {response_length: 0, None: 1}  # a new process knows only these
        self.handles.clear()
        _, channel = await loop.connect_accepted_socket(
            lambda: p.Channel(self.on_message, self.on_lost), ours)
        self.channel = channel
        trace = logging.getLogger("drivebus.trace").getEffectiveLevel()
        level = logging.getLogger("drivebus").getEffectiveLevel()
        self.send((p.OPEN, [(s.config, s.timeout, s.retries) for s in self.specs], level,
                   trace))
        try:
            with anyio.fail_after(START_TIMEOUT):
                error = await self._ready
        except (TimeoutError, ConnectionLost) as exc:
            await self._end()
            raise DrivebusError(f"worker {self.number} for line {', '.join(self.names)} "
                                f"did not start: {exc or 'no answer'}") from None
        if error is not None:
            await self._end()
            raise p.decode_error(error)
        self.heard = monotonic()
        self.down = None
        for bus in self.buses:
            bus._reattached()
        log.info("worker %d (pid %d) serves line %s", self.number, self.proc.pid,
                 ", ".join(self.names))

    async def close(self) -> None:
        """Have the worker close its lines and end (killed if it does not, in time)."""
        for bus in self.buses:
            bus._open = False
        if self.channel is not None:
            self._closing = True
            self._closed = asyncio.get_running_loop().create_future()
            self.send((p.CLOSE,))
            with anyio.move_on_after(CLOSE_TIMEOUT):
                await self._closed
        await self._end()

    async def _end(self) -> None:
        self._closing = True
        if self.channel is not None:
            self.channel.close()
            self.channel = None
        proc = self.proc
        if proc is None:
            return
        try:
            await anyio.to_thread.run_sync(proc.wait, CLOSE_TIMEOUT, abandon_on_cancel=True)
        except subprocess.TimeoutExpired:
            proc.kill()
            await anyio.to_thread.run_sync(proc.wait)


class WorkerPool:
    """A machine's worker processes, each serving some of its lines: ``buses`` by line."""

    def __init__(self, placement: Sequence[Sequence[LineSpec]],
                 lines: dict[str, Line],
                 on_lost: Callable[[list[str], ConnectionLost], None]) -> None:
        self.on_lost = on_lost
        self.workers = [_Worker(i, specs, [lines[s.name] for s in specs], self)
                        for i, specs in enumerate(placement) if specs]
        self.buses: dict[str, RemoteBus] = {
            s.name: w.buses[i] for w in self.workers for i, s in enumerate(w.specs)}
        self._tasks: ServiceTasks | None = None
        self._lost: list[_Worker] = []
        self._wake = asyncio.Event()

    async def __aenter__(self) -> WorkerPool:
        try:
            async with anyio.create_task_group() as tg:
                for w in self.workers:
                    tg.start_soon(w.start)
        except BaseException:
            with anyio.CancelScope(shield=True):
                await self._close_all()
            raise
        self._tasks = ServiceTasks()
        await self._tasks.__aenter__()
        self._tasks.start_soon(self._supervise, name="drivebus workers' supervisor")
        self._tasks.start_soon(self._watch, name="drivebus workers' watchdog")
        return self

    async def __aexit__(self, *exc: object) -> None:
        try:
            if self._tasks is not None:
                self._tasks.cancel()  # restarts under way end here
                await self._tasks.__aexit__(None, None, None)
        finally:
            with anyio.CancelScope(shield=True):
                await self._close_all()

    async def _close_all(self) -> None:
        async with anyio.create_task_group() as tg:
            for w in self.workers:
                tg.start_soon(w.close)

    def lost(self, worker: _Worker) -> None:
        """``worker`` died: its axes go Offline now, and it is started again."""
        assert worker.down is not None
        self.on_lost(worker.names, worker.down)
        self._lost.append(worker)
        self._wake.set()

    async def _supervise(self) -> None:
        """Start again each worker that died, one after the other."""
        while True:
            await self._wake.wait()
            self._wake.clear()
            while self._lost:
                await self._restart(self._lost.pop(0))

    async def _watch(self) -> None:
        """Kill each serving worker not heard from for ``p.WATCHDOG`` seconds (``hung``).
        A watchdog that itself waited long for the CPU judges nobody that turn: the
        messages that came meanwhile are not taken in yet."""
        period = p.ALIVE_PERIOD
        while True:
            asked = monotonic()
            await anyio.sleep(period)
            for _ in range(2):  # two turns: what a select after the wake-up found has been
                await anyio.lowlevel.checkpoint()  # taken in (its callbacks ran after ours)
            now = monotonic()
            if now - asked > 2 * period:  # our own loop was held: silence says nothing
                for w in self.workers:
                    w.heard = max(w.heard, now)
                continue
            for w in self.workers:
                silent = now - w.heard
                if w.serving and silent > p.WATCHDOG:
                    w.hung(silent)

    async def _restart(self, worker: _Worker) -> None:
        with contextlib.suppress(Exception):
            await worker._end()
        delay = 0.2
        problem: Exception | None = None
        while worker.restarts < RESTARTS:
            worker.restarts += 1
            try:
                await worker.start()
            except DrivebusError as exc:
                problem = exc
                log.warning("worker %d for line %s: restart %d failed: %s", worker.number,
                            ", ".join(worker.names), worker.restarts, exc)
                await anyio.sleep(delay)
                delay *= 2
                continue
            log.warning("worker %d for line %s started again (restart %d of %d)",
                        worker.number, ", ".join(worker.names), worker.restarts, RESTARTS)
            return
        worker.down = ConnectionLost(
            f"the worker process serving line {', '.join(worker.names)} died and could not "
            f"be started again ({problem or 'too many restarts'}): its axes stay Offline")
        log.error("%s", worker.down)

    def info(self) -> list[dict[str, Any]]:
        """Each worker as plain data: its lines, process id, restarts and state."""
        return [{"lines": w.names, "pid": w.pid, "restarts": w.restarts,
                 "state": "serving" if w.down is None else str(w.down)}
                for w in self.workers]


def placement(names: Sequence[str], workers: int) -> list[list[str]]:
    """``names`` spread over ``workers`` workers, in turn."""
    out: list[list[str]] = [[] for _ in range(workers)]
    for i, name in enumerate(names):
        out[i % workers].append(name)
    return [group for group in out if group]


LINES_PER_WORKER = 4
"""For ``workers = "auto"``: the busy lines one process serves at the wire's pace (with
room to spare: about 0.1 core each after issue 37)."""


def auto_workers(lines: int, cores: int | None = None) -> int:
    """How many workers ``workers = "auto"`` starts: none for a few lines or a single
    core; else one per ``LINES_PER_WORKER`` lines, leaving a core to the machine."""
    cores = (os.cpu_count() or 1) if cores is None else cores
    if lines <= LINES_PER_WORKER or cores < 2:
        return 0
    return max(1, min(cores - 1, -(-lines // LINES_PER_WORKER)))
