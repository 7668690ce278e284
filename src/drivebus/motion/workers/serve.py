"""A worker process: serves some of a machine's lines for it, each with its own bus.

Started by the machine (``python -m drivebus.motion.workers.serve FD``, ``FD`` its end of
the socket to the machine), it opens the lines it is given, runs their schedulers and
timing, and carries out the transactions the machine sends, answering each with its reply
or error; it sends each line's statistics, the transactions of observed lines and its log
records. It ignores SIGINT and SIGTERM: when the machine's owner ends, the machine's stops
still need the lines, and the machine closes its workers after them. It ends when the
machine closes it, or when the machine's end of the socket goes away.
"""

from __future__ import annotations

import asyncio
import contextlib
import functools
import logging
import signal
import socket
import sys
from collections.abc import Callable
from typing import Any

import anyio
import anyio.abc

import drivebus.motion.workers.protocol as p
from drivebus import heap
from drivebus.bus import Bus, Priority, SlaveHandle, Transaction
from drivebus.bus.scheduler import Queued
from drivebus.bus.sent import sent_requests
from drivebus.config import LineConfig
from drivebus.errors import ConnectionLost, DrivebusError, LineClosed
from drivebus.motion.lines import make_line
from drivebus.pdu import LengthPredictor, response_length

__all__ = ["main", "serve"]

log = logging.getLogger("drivebus.motion.workers.serve")  # also when run as __main__

STATS_PERIOD = p.ALIVE_PERIOD
"""How often a line's statistics go to the machine (when they changed), seconds."""


class _LogForward(logging.Handler):
    """Sends the worker's log records to its machine, which logs them as its own."""

    def __init__(self, channel: p.Channel) -> None:
        super().__init__()
        self.channel = channel

    def emit(self, record: logging.LogRecord) -> None:
        try:
            self.channel.send((p.LOG, record.name, record.levelno, record.getMessage()))
        except Exception:
            self.handleError(record)


class _Worker:
    """The worker's state: its buses, the slave handles and requests the machine made."""

    def __init__(self, tg: anyio.abc.TaskGroup) -> None:
        self.tg = tg
        self.channel: p.Channel | None = None
        self.buses: list[Bus] = []
        self.handles: dict[int, SlaveHandle] = {}
        self.expects: dict[int, LengthPredictor | None] = {0: response_length, 1: None}
        self.pending: dict[int, tuple[Bus, Queued]] = {}
        self.holds: dict[int, anyio.Event] = {}
        self.holds_now: dict[int, Callable[[], None]] = {}
        self.observing: dict[int, Any] = {}
        self.seen: dict[int, list[Transaction]] = {}
        self.opened = anyio.Event()
        self.config: tuple[Any, ...] | None = None
        self.done = anyio.Event()

    def send(self, message: tuple[Any, ...]) -> None:
        assert self.channel is not None
        self.channel.send(message)

    # -- messages from the machine -----------------------------------------------------------

    def on_message(self, m: tuple[Any, ...]) -> None:
        tag = m[0]
        try:
            if tag == p.TX:
                self._tx(*m[1:])
            elif tag == p.HANDLE:
                self._handle(*m[1:])
            elif tag == p.CANCEL:
                self._cancel(m[1])
            elif tag == p.HOLD:
                self._hold(m[1], m[2])
            elif tag == p.HOLD_NOW:
                self.holds_now[m[1]] = self.buses[m[2]].hold_now()
            elif tag == p.UNHOLD:
                event = self.holds.pop(m[1], None)
                if event is not None:
                    event.set()
                release = self.holds_now.pop(m[1], None)
                if release is not None:
                    release()
            elif tag == p.EXPECT:
                self.expects[m[1]] = m[2]
            elif tag == p.FORGET:
                self.handles.pop(m[1], None)
            elif tag == p.OBSERVE:
                self._observe(m[1], m[2])
            elif tag == p.OPEN:
                self.config = m[1:]
                self.opened.set()
            elif tag == p.CLOSE:
                self.done.set()
        except Exception as exc:
            log.error("worker: message %r failed: %r", tag, exc)

    def on_lost(self, exc: BaseException | None) -> None:
        self.done.set()  # the machine went away: close the lines and end
        self.opened.set()

    def _handle(self, hid: int, line: int, address: int, settings: Any, timeout: float,
                retries: int, guard: float, frame_timeout: float) -> None:
        h = self.handles.get(hid)
        if h is None:
            h = self.buses[line].slave(address, settings=settings, timeout=timeout,
                                       retries=retries, guard=guard,
                                       frame_timeout=frame_timeout)
            self.handles[hid] = h
            return
        h.timeout, h.retries, h.guard, h.frame_timeout = timeout, retries, guard, frame_timeout

    def _tx(self, rid: int, hid: int, pdu: bytes, expect: int, priority: int,
            idempotent: bool) -> None:
        h = self.handles.get(hid)
        if h is None or expect not in self.expects:
            what = f"slave handle {hid}" if h is None else f"reply length {expect}"
            err = ConnectionLost(f"{what} is not known to the worker (it was restarted?)")
            self.send((p.ERR, rid, p.encode_error(err)))
            return
        bus = h.bus
        assert isinstance(bus, Bus)
        try:
            q = bus.queue(h, pdu, expect=self.expects[expect], priority=Priority(priority),
                          idempotent=idempotent)
        except DrivebusError as exc:
            self.send((p.ERR, rid, p.encode_error(exc)))
            return
        self.pending[rid] = (bus, q)
        q.future.add_done_callback(functools.partial(self._done, rid))
        if priority >= Priority.EMERGENCY:
            self.send((p.TAKEN, self.buses.index(bus), q.queued_at))  # type: ignore[attr-defined]  # (a Request)

    def _done(self, rid: int, fut: asyncio.Future[bytes]) -> None:
        if self.pending.pop(rid, None) is None or fut.cancelled():
            return  # taken back by the machine: ``_retract`` answers for it
        exc = fut.exception()
        if exc is None:
            self.send((p.OK, rid, fut.result()))
        else:
            self.send((p.ERR, rid, p.encode_error(exc)))

    def _cancel(self, rid: int) -> None:
        entry = self.pending.pop(rid, None)
        if entry is None:  # it had ended: its reply or error is on its way
            self.send((p.CANCELLED, rid, None, True))
            return
        self.tg.start_soon(self._retract, rid, *entry)

    async def _retract(self, rid: int, bus: Bus, q: Queued) -> None:
        with sent_requests() as noted:
            await bus.retract(q)
        self.send((p.CANCELLED, rid, noted[0] if noted else None, False))

    def _hold(self, hid: int, line: int) -> None:
        release = self.holds[hid] = anyio.Event()
        self.tg.start_soon(self._held, hid, self.buses[line], release)

    async def _held(self, hid: int, bus: Bus, release: anyio.Event) -> None:
        try:
            async with bus.hold():
                self.send((p.HELD, hid, None))
                await release.wait()
        except DrivebusError as exc:
            self.holds.pop(hid, None)
            self.send((p.HELD, hid, p.encode_error(exc)))

    def _observe(self, line: int, on: bool) -> None:
        end = self.observing.pop(line, None)
        if end is not None:
            end()
        if on:
            self.observing[line] = self.buses[line].observe(
                functools.partial(self._seen, line))

    def _seen(self, line: int, tx: Transaction) -> None:
        batch = self.seen.get(line)
        if batch is None:
            batch = self.seen[line] = []
            asyncio.get_running_loop().call_soon(self._flush_seen, line)
        batch.append(tx)

    def _flush_seen(self, line: int) -> None:
        batch = self.seen.pop(line, None)
        if batch:
            self.send((p.SEEN, line, batch))

    # -- the lines -------------------------------------------------------------------------

    async def serve(self, lines: list[tuple[LineConfig, float, float]]) -> None:
        """Open the lines, serve them until told to close, close them."""
        async with contextlib.AsyncExitStack() as stack:
            try:
                for cfg, timeout, retries in lines:
                    bus = Bus(make_line(cfg), timeout=timeout, retries=int(retries))
                    self.buses.append(await stack.enter_async_context(bus))
            except (DrivebusError, OSError) as exc:
                self.send((p.READY, p.encode_error(exc)))
                return
            heap.settle()  # (before the first request: see drivebus.heap)
            self.send((p.READY, None))
            async with anyio.create_task_group() as tg:
                tg.start_soon(self._stats_loop)
                await self.done.wait()
                tg.cancel_scope.cancel()
            self.send_stats(force=True)
            for bus, q in list(self.pending.values()):
                if not q.future.done():
                    q.future.set_exception(LineClosed(f"bus on {bus.line.name} closed"))
        self.send((p.CLOSED,))

    def send_stats(self, *, force: bool = False, sent: dict[int, int] | None = None) -> None:
        """Each line's statistics (those that changed since ``sent``, or all)."""
        for i, bus in enumerate(self.buses):
            n = bus.stats.transactions
            if force or sent is None or sent.get(i) != n:
                self.send((p.STATS, i, bus.stats, bus.line.garbage_bytes))
                if sent is not None:
                    sent[i] = n

    async def _stats_loop(self) -> None:
        """The statistics that changed and a word that the worker is alive, every period
        (``p.ALIVE_PERIOD``: the machine's watchdog counts on it)."""
        sent: dict[int, int] = {}
        while True:
            self.send_stats(sent=sent)
            self.send((p.ALIVE,))
            await anyio.sleep(STATS_PERIOD)


async def serve(fd: int) -> None:
    """Serve the machine at the other end of socket ``fd`` until it closes us."""
    loop = asyncio.get_running_loop()
    sock = socket.socket(fileno=fd)
    async with anyio.create_task_group() as tg:
        worker = _Worker(tg)
        _, channel = await loop.connect_accepted_socket(
            lambda: p.Channel(worker.on_message, worker.on_lost), sock)
        worker.channel = channel
        await worker.opened.wait()
        if worker.config is not None:
            lines, level, trace_level = worker.config
            root = logging.getLogger()
            root.handlers[:] = [_LogForward(channel)]
            root.setLevel(level)
            logging.getLogger("drivebus.trace").setLevel(trace_level)
            await worker.serve(lines)
        channel.close()
        tg.cancel_scope.cancel()


def main() -> None:
    """``python -m drivebus.motion.workers.serve FD``."""
    # The machine's own shutdown stops go through us: its owner's signals are not ours.
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, signal.SIG_IGN)
    anyio.run(serve, int(sys.argv[1]))


if __name__ == "__main__":
    main()
