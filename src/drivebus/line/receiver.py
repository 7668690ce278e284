"""RtuReceiver: assembles RTU replies from a byte stream (serial port or TCP socket).

End of frame is found by length (function code and byte count); after garbage, a bad
CRC or a short frame it waits for t3.5 of silence and then looks for a valid frame.
Every step does bounded work: the buffer keeps at most ``BUFFER_LIMIT`` bytes, a wait for
silence wakes once per silence (not per byte) and ends at a limit, and the search for a
frame in junk checks at most ``SCAN_CRC_BUDGET`` bytes of CRC. A line flooded with bytes
therefore costs bounded CPU per wake-up and ends in ``LineNoise``, never in a hang.
"""

from __future__ import annotations

import asyncio
import os
from collections import deque
from collections.abc import Callable
from typing import cast

from drivebus.clock import cpu_wait, monotonic, stall_grace
from drivebus.errors import FrameError, LineClosed, LineNoise, ResponseTimeout, WrongResponder
from drivebus.line.foreign import find_requests
from drivebus.line.rtu import crc_ok
from drivebus.pdu import LengthPredictor

__all__ = [
    "BUFFER_LIMIT",
    "MAX_ADU",
    "SCAN_CRC_BUDGET",
    "RtuReceiver",
    "StreamProtocol",
    "read_waiting",
]

MAX_ADU = 256
"""The longest RTU frame (Modbus over serial line, 2.5.1.1)."""
BUFFER_LIMIT = 2 * MAX_ADU
"""Received bytes kept at most: a reply and as much junk before it; older bytes go."""
SCAN_CRC_BUDGET = 8 * 1024
"""Bytes of CRC computed at most when looking for a frame in junk (a few ms of CPU)."""
_NEVER = BUFFER_LIMIT + 1
"""A byte count the buffer never reaches: ``wait_for(_NEVER, t)`` waits for ``t`` only."""
STALL_EXTENSIONS = 2
"""Times a reply deadline that passed while the process was not running is extended
(``drivebus.clock.stall_grace``): a dead slave still times out on a busy machine."""


def read_waiting(fd: int) -> bytes:
    """What a non-blocking descriptor (serial port, socket) has received and nobody has read
    yet, up to ``BUFFER_LIMIT`` bytes; empty if nothing (or the descriptor failed: its
    transport will report that itself)."""
    try:
        return os.read(fd, BUFFER_LIMIT)
    except OSError:  # EAGAIN: nothing waiting; EIO/ECONNRESET: the transport will see it
        return b""


def _loop_time(loop: asyncio.AbstractEventLoop, t: float) -> float:
    # asyncio's loop clock is time.monotonic; keep the conversion in one place anyway.
    return t - monotonic() + loop.time()


class StreamProtocol(asyncio.Protocol):
    """An asyncio protocol on a byte stream (serial port, TCP socket) that keeps its
    transport and, once the stream is gone, why."""

    def __init__(self, name: str = "line", *, line_name: str | None = None) -> None:
        self.name = name
        """What error messages call the stream (e.g. "serial port /dev/ttyUSB0")."""
        self.line_name = name if line_name is None else line_name
        """The name of the line it belongs to (``Line.name``), for typed errors."""
        self.transport: asyncio.Transport | None = None
        self.lost: BaseException | None = None
        """Why the stream ended (None while it is up)."""

    def connection_made(self, transport: asyncio.BaseTransport) -> None:
        # Serial ports and TCP sockets both give a (read/write) ``asyncio.Transport``.
        self.transport = cast(asyncio.Transport, transport)

    def send(self, data: bytes) -> None:
        """Queue ``data`` on the transport; ``LineClosed`` if the stream is not up."""
        transport = self.transport
        if transport is None or self.lost is not None:
            raise LineClosed(f"{self.name} is not connected")
        transport.write(data)


class RtuReceiver(StreamProtocol):
    """Stream protocol collecting received bytes with the arrival time of the last one.

    It holds at most ``BUFFER_LIMIT`` bytes: older ones are dropped (and counted as
    garbage) as newer ones come, so a flooded line costs one bounded copy per read.
    """

    def __init__(self, name: str = "line", *, line_name: str | None = None) -> None:
        super().__init__(name, line_name=line_name)
        self.buf = bytearray()
        self.last_rx = 0.0
        self.need = 0
        self.waiter: asyncio.Future[None] | None = None
        self.garbage_bytes = 0
        """Bytes received outside any reply (late answers, noise), discarded."""
        self.pending_bytes: Callable[[], bytes] | None = None
        """Reads what the medium has received and the event loop has not delivered yet
        (set by lines that can, e.g. a serial port's non-blocking read)."""
        self.asked: deque[tuple[int, int]] = deque(maxlen=4)
        """(address, function code) of the master's own last requests: what a late reply
        or an echo among the discarded bytes answers (``drivebus.line.foreign``)."""
        self.on_foreign: Callable[[bytes], None] | None = None
        """Called with each request of another master found among the discarded bytes."""
        self._expiry: asyncio.TimerHandle | None = None

    # -- asyncio.Protocol --------------------------------------------------------------------

    def data_received(self, data: bytes) -> None:
        self.last_rx = monotonic()
        buf = self.buf
        buf += data
        excess = len(buf) - BUFFER_LIMIT
        if excess > 0:
            del buf[:excess]  # a reply is at most MAX_ADU bytes: these cannot all be one
            self.garbage_bytes += excess
        w = self.waiter
        if w is not None and len(buf) >= self.need and not w.done():
            w.set_result(None)

    def connection_lost(self, exc: Exception | None) -> None:
        self.lost = exc or LineClosed(f"{self.name} closed")
        w = self.waiter
        if w is not None and not w.done():
            w.set_exception(LineClosed(f"{self.name} lost: {self.lost}"))

    def take_pending(self) -> None:
        """Take in bytes received but not delivered yet, so that ``last_rx`` is up to date
        before a decision on silence (the loop may have been busy elsewhere)."""
        if self.pending_bytes is not None:
            late = self.pending_bytes()
            if late:
                self.data_received(late)

    # -- waiting -------------------------------------------------------------------------------

    async def wait_for(self, n: int, deadline: float, *, patient: bool = True) -> bool:
        """Wait until ``n`` bytes are buffered; False if ``deadline`` passed first
        (``patient``: a deadline that passed while the process was not running is
        extended, see ``expect_bytes``).

        ``n`` beyond ``BUFFER_LIMIT`` is never reached: that waits for the deadline (or
        the loss of the stream) only.
        """
        if len(self.buf) >= n:
            return True
        if self.lost is not None:
            raise LineClosed(f"{self.name} lost: {self.lost}")
        w: asyncio.Future[None] = asyncio.get_running_loop().create_future()
        self.expect_bytes(n, deadline, w, patient=patient)
        try:
            await w
        finally:
            self.release()
        return len(self.buf) >= n

    def expect_bytes(
        self, n: int, deadline: float, waiter: asyncio.Future[None], *, patient: bool = True
    ) -> None:
        """Resolve ``waiter`` once ``n`` bytes are buffered or ``deadline`` has come,
        whichever is first (an exception if the stream is lost); ``release()`` ends it.

        ``patient``: if the process was held up meanwhile (its thread waited for a CPU,
        or the deadline's timer ran late), the bytes are looked for once more and the wait
        is extended by the time lost and a moment (``stall_grace``, at most
        ``STALL_EXTENSIONS`` times): a slave that could not run either, a simulator in
        this process, gets the time it needs to answer."""
        loop = waiter.get_loop()
        self.need = n
        self.waiter = waiter
        extensions = STALL_EXTENSIONS if patient else 0
        self._expiry = loop.call_at(_loop_time(loop, deadline), self._expire, waiter,
                                    deadline, extensions, cpu_wait() if patient else 0.0)
        if self.lost is not None:
            waiter.set_exception(LineClosed(f"{self.name} lost: {self.lost}"))
        elif len(self.buf) >= n:
            waiter.set_result(None)

    def _expire(self, waiter: asyncio.Future[None], deadline: float, extensions: int,
                waited_before: float) -> None:
        if waiter.done():
            return
        if extensions:
            waited = cpu_wait()
            grace = stall_grace(monotonic() - deadline, waited - waited_before)
            if grace:
                self.take_pending()  # resolves the waiter if what it waits for is there
                if waiter.done() or self.waiter is not waiter:
                    return
                until = monotonic() + grace
                loop = waiter.get_loop()
                self._expiry = loop.call_at(_loop_time(loop, until), self._expire, waiter,
                                            until, extensions - 1, waited)
                return
        waiter.set_result(None)

    def release(self) -> None:
        """Stop resolving the waiter of ``expect_bytes``."""
        if self._expiry is not None:
            self._expiry.cancel()
            self._expiry = None
        self.waiter = None

    async def wait_silence(self, silence: float, limit: float) -> bool:
        """Wait until ``silence`` has passed since the last byte; False if ``limit`` came
        first (bytes kept arriving). Wakes once per silence, not once per byte."""
        while True:
            now = monotonic()
            quiet_at = self.last_rx + silence
            if now >= quiet_at:
                self.take_pending()
                if monotonic() >= self.last_rx + silence:
                    return True
                continue  # bytes were waiting: not quiet after all
            if now >= limit:
                return False
            await self.wait_for(_NEVER, min(quiet_at, limit), patient=False)

    def discard(self) -> None:
        """Drop whatever is buffered (bytes that arrived outside a reply)."""
        if self.buf:
            self._drop(bytes(self.buf))
            self.buf.clear()

    def _drop(self, data: bytes, kept: int = 0) -> None:
        """Count ``data`` (less ``kept`` bytes of it that were a reply) as garbage, and
        report the requests of another master among it (``on_foreign``)."""
        self.garbage_bytes += len(data) - kept
        if self.on_foreign is not None and len(data) >= 8:
            for request in find_requests(data, self.asked):
                self.on_foreign(request)

    async def take_echo(self, adu: bytes, deadline: float) -> None:
        """Consume the local echo of ``adu`` (adapters that hear their own transmitter)."""
        if not await self.wait_for(len(adu), deadline) or bytes(self.buf[: len(adu)]) != adu:
            got = bytes(self.buf[: len(adu)])
            self.buf.clear()
            raise FrameError(
                f"local echo {got.hex(' ')} differs from the frame sent {adu.hex(' ')}: "
                "bus collision, or the adapter does not echo (set local_echo = false)"
            )
        del self.buf[: len(adu)]

    async def read_reply(
        self, unit: int, expect: LengthPredictor, deadline: float, char: float, t35: float
    ) -> bytes:
        """The reply PDU from ``unit``, read by length; typed error if there is none."""
        buf = self.buf
        need = 3  # address, function code and a byte count: the shortest reply has 4 bytes
        extended = False
        # A reply that does not start where expected may still come after junk; it is
        # given the wire time of the longest frame beyond the deadline to end.
        resync_limit = deadline + MAX_ADU * char + 2 * t35
        while True:
            if len(buf) < need and not await self.wait_for(need, deadline):
                if buf:
                    return await self._resync(unit, expect, t35, resync_limit)
                raise ResponseTimeout(f"slave {unit} on {self.line_name}: no reply", slave=unit)
            if buf[0] != unit:
                return await self._resync(unit, expect, t35, resync_limit)
            length = expect(bytes(buf[1:need]))
            if length is None:
                need += 1
                continue
            total = 1 + length + 2
            if not extended:
                deadline += total * char  # allow the reply's own wire time
                extended = True
            if len(buf) < total:
                need = total
                continue
            adu = bytes(buf[:total])
            if not crc_ok(adu):
                return await self._resync(unit, expect, t35, resync_limit)
            del buf[:total]  # anything after it is garbage, dropped before the next frame
            return adu[1:-2]

    async def _resync(
        self, unit: int, expect: LengthPredictor, t35: float, limit: float
    ) -> bytes:
        """Error path: wait for t3.5 of silence, then look for a valid frame in the bytes.

        If bytes are still coming at ``limit`` the reply is lost in noise: ``LineNoise``.
        """
        if not await self.wait_silence(t35, limit):
            dropped = len(self.buf)
            self.discard()
            raise LineNoise(
                f"slave {unit}: reply lost in noise on {self.name}: bytes kept arriving with "
                f"no silence of {t35 * 1e3:.2f} ms ({dropped} kept at the end, "
                f"{self.garbage_bytes} discarded on this line so far)",
                slave=unit,
                line=self.line_name,
                sent=True,
            )
        data = bytes(self.buf)
        self.buf.clear()
        found, other = _scan(data, unit, expect)
        self._drop(data, 0 if found is None else len(found) + 3)
        if found is not None:
            return found
        if other is not None:
            raise WrongResponder(
                f"slave {unit} on {self.line_name}: reply came from address {other}",
                slave=unit,
                responder=other,
            )
        kind = "bad CRC" if len(data) >= 4 else "short frame"
        raise FrameError(
            f"slave {unit} on {self.line_name}: unusable reply ({kind}, {len(data)} bytes: "
            f"{data[:32].hex(' ')})",
            slave=unit,
        )


def _scan(data: bytes, unit: int, expect: LengthPredictor) -> tuple[bytes | None, int | None]:
    """The first valid frame from ``unit`` in ``data`` (its PDU), and the address of the first
    valid frame from another address. CRC checks stop after ``SCAN_CRC_BUDGET`` bytes, so
    adversarial junk (every byte a plausible frame start) costs bounded time."""
    budget = SCAN_CRC_BUDGET
    other: int | None = None
    for i in range(len(data) - 3):
        length = expect(data[i + 1 : i + 1 + MAX_ADU])
        if length is None or i + length + 3 > len(data):
            continue
        budget -= length + 3
        if budget < 0:
            break
        adu = data[i : i + length + 3]
        if crc_ok(adu):
            if adu[0] == unit:
                return adu[1:-2], other
            other = adu[0] if other is None else other
    return None, other
