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
import math
import os
import select
from collections import deque
from collections.abc import Callable
from typing import Protocol, cast

from drivebus.clock import DeadlineTimer, cpu_wait_of, cpu_wait_stamp, monotonic, stall_grace
from drivebus.errors import FrameError, LineClosed, LineNoise, ResponseTimeout, WrongResponder
from drivebus.line.foreign import find_requests
from drivebus.line.rtu import crc16_value, crc_ok
from drivebus.pdu import LengthPredictor, response_length

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
_KIND = tuple(
    1 if fc in (0x01, 0x02, 0x03, 0x04, 0x17) else 2 if fc in (0x05, 0x06, 0x08, 0x0F, 0x10)
    else 3 if fc & 0x80 else 0
    for fc in range(256)
)
"""By function code, the length of a standard reply (``response_length``'s): 1 its data's
byte count in its third byte, 2 eight bytes, 3 an exception (five), 0 not known."""
_NEVER = BUFFER_LIMIT + 1
"""A byte count the buffer never reaches: ``wait_for(_NEVER, t)`` waits for ``t`` only."""
STALL_EXTENSIONS = 2
"""Times a reply deadline that passed while the process was not running is extended
(``drivebus.clock.stall_grace``): a dead slave still times out on a busy machine."""
CPU_WAIT_MARK_AGE = 0.01
"""How old (s) the thread's CPU-wait mark a reply wait starts from may be: a line busy
with back-to-back transactions reads it (a read of /proc) for one in several, not for
each. A deadline then counts the CPU wait since up to this long before its request left:
a process held up just before the request had a simulated slave in it held up as well."""


def read_waiting(fd: int) -> bytes:
    """What a non-blocking descriptor (serial port, socket) has received and nobody has read
    yet, up to ``BUFFER_LIMIT`` bytes; empty if nothing (or the descriptor failed: its
    transport will report that itself)."""
    try:
        return os.read(fd, BUFFER_LIMIT)
    except OSError:  # EAGAIN: nothing waiting; EIO/ECONNRESET: the transport will see it
        return b""


class Waiter(Protocol):
    """What the receiver resolves when a wait ends: an ``asyncio.Future``, or a serial
    job (``drivebus.line.link.RtuJob``) that makes its future only when it is needed."""

    def done(self) -> bool:
        """Whether it has been resolved."""
        ...

    def set_result(self, result: None) -> None:
        """Resolve it: the wait is over (the task looks at what is there)."""
        ...

    def set_exception(self, exc: BaseException) -> None:
        """Fail it (the stream was lost)."""
        ...


_EARLY = 1e-6
"""How early the loop may run a timer (its clock's resolution and rounding): a waiter's
deadline counts as come within this."""


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

    A reply awaited with ``expect_reply`` is assembled here, as its bytes arrive: once it
    is complete by length, from the right address and with a good CRC, ``on_frame`` gets
    its PDU from the very callback that received its last byte, and the waiting task is
    woken once, with the work done. Anything else (a wrong address, a bad CRC, the
    deadline) wakes the task with the bytes as they are, for ``read_reply`` to judge.
    """

    def __init__(self, name: str = "line", *, line_name: str | None = None) -> None:
        super().__init__(name, line_name=line_name)
        self.buf = bytearray()
        self.last_rx = 0.0
        self.need = 0
        self.waiter: Waiter | None = None
        self.garbage_bytes = 0
        """Bytes received outside any reply (late answers, noise), discarded."""
        self._pending_fd = -1
        self._pending_poll: select.poll | None = None
        """Asks the descriptor of ``watch`` whether bytes wait (one ``poll`` of no time:
        on an idle line, the rule before a frame, that spares a read's EAGAIN)."""
        self._deadline = 0.0
        """When the waiter is resolved at the latest (monotonic)."""
        self.asked: deque[bytes] = deque(maxlen=4)
        """The master's own last request frames (their address and function code): what a
        late reply or an echo among the discarded bytes answers
        (``drivebus.line.foreign``)."""
        self.on_foreign: Callable[[bytes], None] | None = None
        """Called with each request of another master found among the discarded bytes."""
        self._extensions = 0
        """Times the waiter's deadline may still be extended for a stall (``_expired``)."""
        self._waited_before = b""
        """The thread's CPU wait when the waiter's wait began (``cpu_wait_stamp``: read at
        most ``CPU_WAIT_MARK_AGE`` before it, made seconds only when a deadline comes)."""
        self._marked_at = -math.inf
        """When ``_waited_before`` was read (monotonic)."""
        self._expiry = DeadlineTimer()
        """The one timer of the waits' deadlines (see ``_wait``); a timerfd, so that an
        armed deadline costs the event loop nothing on its turns (an asyncio timer would
        make each of them read the clock and work out its timeout)."""
        self._expiry_set = False
        """``_expiry`` is armed (for ``_expired``)."""
        self._expiry_at = 0.0
        """When ``_expiry`` fires (monotonic): the earliest deadline since it was set."""
        self._unit = 0
        self._expect: LengthPredictor | None = None
        """The reply being assembled: its length predictor (None: plain byte count)."""
        self._on_frame: Callable[[bytes], None] | None = None

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
            if self._expect is None:
                w.set_result(None)
            else:
                self._assemble(w)

    def connection_lost(self, exc: Exception | None) -> None:
        self.lost = exc or LineClosed(f"{self.name} closed")
        w = self.waiter
        if w is not None and not w.done():
            w.set_exception(LineClosed(f"{self.name} lost: {self.lost}"))
        self._expiry_set = False
        self._expiry.close()

    def watch(self, fd: int) -> None:
        """Let ``take_pending`` read what ``fd`` (the non-blocking serial port or socket
        the transport reads) has received and the event loop has not delivered yet."""
        self._pending_fd = fd
        self._pending_poll = select.poll()
        self._pending_poll.register(fd, select.POLLIN | select.POLLERR | select.POLLHUP)

    def take_pending(self) -> None:
        """Take in bytes received but not delivered yet, so that ``last_rx`` is up to date
        before a decision on silence (the loop may have been busy elsewhere)."""
        poll = self._pending_poll
        if poll is not None and poll.poll(0):
            late = read_waiting(self._pending_fd)
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
        self._expect = None
        if patient:
            self._extensions = STALL_EXTENSIONS
            self._mark(monotonic())
        else:
            self._extensions = 0
        self._wait(n, deadline, waiter)

    def expect_reply(
        self, unit: int, expect: LengthPredictor, deadline: float,
        waiter: Waiter, on_frame: Callable[[bytes], None], now: float,
    ) -> None:
        """Assemble the reply from ``unit`` as it arrives: once it is complete (by
        ``expect``), from ``unit`` and with a good CRC, take it out of the buffer and call
        ``on_frame`` with its PDU (which resolves ``waiter``). Anything else resolves
        ``waiter`` with the bytes left as they are: something other than ``unit``'s frame
        at the start, a bad CRC, ``deadline`` (an exception if the stream is lost).
        ``release()`` ends it. ``now``: the time (monotonic) its request left, just now."""
        self._unit = unit
        self._expect = expect
        self._on_frame = on_frame
        self.need = 3  # address, function code and a byte count
        self.waiter = waiter
        self._deadline = deadline
        self._extensions = STALL_EXTENSIONS  # (a stall extends the wait: ``expect_bytes``)
        if now - self._marked_at >= CPU_WAIT_MARK_AGE:  # (``_mark``, written out)
            self._waited_before = cpu_wait_stamp()
            self._marked_at = now
        if not self._expiry_set or self._expiry_at > deadline:  # (``_wait``, written out)
            self._set_expiry(deadline)
        if self.lost is not None:
            waiter.set_exception(LineClosed(f"{self.name} lost: {self.lost}"))
        elif len(self.buf) >= 3:
            self._assemble(waiter)

    def _mark(self, now: float) -> None:
        """Read the thread's CPU wait for the wait that begins ``now``, unless the last
        reading is recent enough (``CPU_WAIT_MARK_AGE``)."""
        if now - self._marked_at >= CPU_WAIT_MARK_AGE:
            self._waited_before = cpu_wait_stamp()
            self._marked_at = now

    def _wait(self, n: int, deadline: float, waiter: Waiter) -> None:
        self.need = n
        self.waiter = waiter
        self._deadline = deadline
        if not self._expiry_set or self._expiry_at > deadline:
            # One timer serves many waits: deadlines mostly come later and later, and a
            # timer that fires before its waiter's deadline is set again then.
            self._set_expiry(deadline)
        if self.lost is not None:
            waiter.set_exception(LineClosed(f"{self.name} lost: {self.lost}"))
        elif len(self.buf) >= n:
            if self._expect is None:
                waiter.set_result(None)
            else:
                self._assemble(waiter)

    def _set_expiry(self, deadline: float) -> None:
        if self.lost is not None:
            return  # (its waiter fails at once; the timer is closed)
        self._expiry_set = True
        self._expiry_at = deadline
        self._expiry.call_at(deadline, self._expired)

    def _expired(self) -> None:
        self._expiry_set = False
        w = self.waiter
        if w is None or w.done():
            return
        now = monotonic()
        if now + _EARLY < self._deadline:  # set for an earlier wait: wait on
            self._set_expiry(self._deadline)
            return
        if self._extensions:
            stamp = cpu_wait_stamp()
            grace = stall_grace(now - self._deadline,
                                cpu_wait_of(stamp) - cpu_wait_of(self._waited_before))
            if grace:  # the process was held up: the reply gets the time it lost
                self.take_pending()  # resolves the waiter if what it waits for is there
                if w.done() or self.waiter is not w:
                    return
                self._extensions -= 1
                self._waited_before = stamp
                self._marked_at = now
                self._deadline = until = monotonic() + grace
                self._set_expiry(until)
                return
        w.set_result(None)

    def _assemble(self, w: Waiter) -> None:
        """The reply so far (at least ``need`` bytes): complete it, ask for more bytes, or
        wake the waiting task to judge what is there."""
        buf = self.buf
        expect: LengthPredictor = self._expect  # type: ignore[assignment]  # (set while assembling)
        if buf[0] != self._unit:
            w.set_result(None)  # not the frame asked for (yet): read_reply resynchronises
            return
        kind = _KIND[buf[1]] if expect is response_length else 0
        if kind == 1:  # the standard replies' lengths, as response_length has them
            total = buf[2] + 5
        elif kind:
            total = 8 if kind == 2 else 5
        else:
            need = 3
            while True:
                length = expect(bytes(buf[1:need]))
                if length is not None:
                    break
                need += 1
                if len(buf) < need:
                    self.need = need
                    return
            total = length + 3
        n = len(buf)
        if n < total:
            self.need = total
            return
        if crc16_value(buf if n == total else buf[:total]):  # not 0: a bad CRC
            w.set_result(None)  # read_reply resynchronises
            return
        pdu = bytes(buf[1:total - 2])
        del buf[:total]  # anything after it is garbage, dropped before the next frame
        on_frame: Callable[[bytes], None] = self._on_frame  # type: ignore[assignment]
        self._expect = self._on_frame = None
        on_frame(pdu)

    def release(self) -> None:
        """Stop resolving the waiter of ``expect_bytes`` or ``expect_reply`` (its timer
        stays for the next wait, or fires once with nobody waiting)."""
        self.waiter = None
        self._expect = self._on_frame = None

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
            asked = {(adu[0], adu[1]) for adu in self.asked}
            for request in find_requests(data, asked):
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
