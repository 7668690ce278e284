"""RtuReceiver: assembles RTU replies from a byte stream (serial port or TCP socket).

End of frame is found by length (function code and byte count); after garbage, a bad
CRC or a short frame it waits for t3.5 of silence and then looks for a valid frame.
"""

from __future__ import annotations

import asyncio
from typing import cast

from drivebus.clock import monotonic
from drivebus.errors import FrameError, LineClosed, ResponseTimeout, WrongResponder
from drivebus.line.rtu import crc_ok
from drivebus.pdu import LengthPredictor

__all__ = ["RtuReceiver", "StreamProtocol"]


def _expire(w: asyncio.Future[None]) -> None:
    if not w.done():
        w.set_result(None)


def _loop_time(loop: asyncio.AbstractEventLoop, t: float) -> float:
    # asyncio's loop clock is time.monotonic; keep the conversion in one place anyway.
    return t - monotonic() + loop.time()


class StreamProtocol(asyncio.Protocol):
    """An asyncio protocol on a byte stream (serial port, TCP socket) that keeps its
    transport and, once the stream is gone, why."""

    def __init__(self, name: str = "line") -> None:
        self.name = name
        """The line's name, for error messages."""
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
    """Stream protocol collecting received bytes with the arrival time of the last one."""

    def __init__(self, name: str = "line") -> None:
        super().__init__(name)
        self.buf = bytearray()
        self.last_rx = 0.0
        self.need = 0
        self.waiter: asyncio.Future[None] | None = None
        self.garbage_bytes = 0
        """Bytes received outside any reply (late answers, noise), discarded."""

    # -- asyncio.Protocol --------------------------------------------------------------------

    def data_received(self, data: bytes) -> None:
        self.last_rx = monotonic()
        self.buf += data
        w = self.waiter
        if w is not None and len(self.buf) >= self.need and not w.done():
            w.set_result(None)

    def connection_lost(self, exc: Exception | None) -> None:
        self.lost = exc or LineClosed(f"{self.name} closed")
        w = self.waiter
        if w is not None and not w.done():
            w.set_exception(LineClosed(f"{self.name} lost: {self.lost}"))

    # -- waiting -------------------------------------------------------------------------------

    async def wait_for(self, n: int, deadline: float) -> bool:
        """Wait until ``n`` bytes are buffered; False if ``deadline`` passed first."""
        if len(self.buf) >= n:
            return True
        if self.lost is not None:
            raise LineClosed(f"{self.name} lost: {self.lost}")
        loop = asyncio.get_running_loop()
        w = self.waiter = loop.create_future()
        self.need = n
        handle = loop.call_at(_loop_time(loop, deadline), _expire, w)
        try:
            await w
        finally:
            handle.cancel()
            self.waiter = None
        return len(self.buf) >= n

    def discard(self) -> None:
        """Drop whatever is buffered (bytes that arrived outside a reply)."""
        if self.buf:
            self.garbage_bytes += len(self.buf)
            self.buf.clear()

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
        need = 2
        extended = False
        while True:
            if not await self.wait_for(need, deadline):
                if buf:
                    return await self._resync(unit, expect, t35, deadline)
                raise ResponseTimeout(f"slave {unit}: no reply", slave=unit)
            if buf[0] != unit:
                return await self._resync(unit, expect, t35, deadline)
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
                return await self._resync(unit, expect, t35, deadline)
            del buf[:total]  # anything after it is garbage, dropped before the next frame
            return adu[1:-2]

    async def _resync(
        self, unit: int, expect: LengthPredictor, t35: float, deadline: float
    ) -> bytes:
        """Error path: wait for t3.5 of silence, then look for a valid frame in the bytes."""
        limit = deadline + 0.5  # a babbling line must not hold us forever
        while monotonic() < limit:
            quiet_at = self.last_rx + t35
            if monotonic() >= quiet_at:
                break
            await self.wait_for(len(self.buf) + 1, min(quiet_at, limit))
        data = bytes(self.buf)
        self.buf.clear()
        other: int | None = None
        for i in range(len(data) - 3):
            length = expect(data[i + 1 :])
            if length is None or i + length + 3 > len(data):
                continue
            adu = data[i : i + length + 3]
            if crc_ok(adu):
                if adu[0] == unit:
                    self.garbage_bytes += len(data) - len(adu)
                    return adu[1:-2]
                other = adu[0] if other is None else other
        self.garbage_bytes += len(data)
        if other is not None:
            raise WrongResponder(
                f"slave {unit}: reply came from address {other}", slave=unit, responder=other
            )
        kind = "bad CRC" if len(data) >= 4 else "short frame"
        raise FrameError(
            f"slave {unit}: unusable reply ({kind}, {len(data)} bytes: {data[:32].hex(' ')})",
            slave=unit,
        )
