"""Misbehaving peers for tests: an RTU slave on the far end of a raw pty and a Modbus TCP
server on loopback, both answering with scripted bytes. The master under test is the real
stack (pyserial on the pty, asyncio sockets)."""

from __future__ import annotations

import asyncio
import contextlib
import os
import struct
import tty
from collections.abc import AsyncIterator, Callable

from drivebus import Bus, LineSettings, SerialLine
from drivebus import pdu as P

FAST = LineSettings.parse("115200 8N1")
UNIT = 1


def values_pdu(values: list[int], function: int = P.READ_HOLDING) -> bytes:
    """A read reply PDU carrying ``values``."""
    return bytes((function, 2 * len(values))) + struct.pack(f">{len(values)}H", *values)


# -- an RTU peer on a raw pty ---------------------------------------------------------------------


class PtyPeer:
    """The far end of a pty: answers each request frame with the next scripted bytes."""

    def __init__(self, master_fd: int, script: list[bytes]) -> None:
        self.fd = master_fd
        self.script = script
        self.rx = bytearray()
        self.requests = 0

    def on_readable(self) -> None:
        try:
            self.rx += os.read(self.fd, 4096)
        except OSError:
            return  # EIO: the master closed its side
        answer = None
        while len(self.rx) >= 8:  # every request here is an 8-byte FC03/FC06 frame
            del self.rx[:8]
            self.requests += 1
            answer = self.script.pop(0) if self.script else None
        # Two requests in one read: this end ran late (a starved machine) and the master
        # has moved on to the last; a slave answering the first on time would have been
        # heard before it, so only the last is answered.
        if answer is not None:
            os.write(self.fd, answer)


@contextlib.asynccontextmanager
async def pty_bus(script: list[bytes], *, timeout: float = 0.05) -> AsyncIterator[Bus]:
    """A Bus over the real serial stack on a pty whose other end is a ``PtyPeer``."""
    master, slave = os.openpty()
    tty.setraw(slave)
    os.set_blocking(master, False)
    peer = PtyPeer(master, script)
    loop = asyncio.get_running_loop()
    loop.add_reader(master, peer.on_readable)
    try:
        async with Bus(SerialLine(os.ttyname(slave), FAST), timeout=timeout, retries=0) as bus:
            yield bus
    finally:
        loop.remove_reader(master)
        os.close(slave)
        os.close(master)


MakeReply = Callable[[int], bytes]
"""The bytes a TCP peer sends back for a request with transaction id ``tid``."""


def mbap(tid: int, pdu: bytes, *, unit: int = UNIT, protocol: int = 0,
          length: int | None = None) -> bytes:
    """An MBAP frame (header fields overridable, to build broken ones) around ``pdu``."""
    n = len(pdu) + 1 if length is None else length
    return struct.pack(">HHHB", tid, protocol, n, unit) + pdu


class TcpPeer:
    """A loopback Modbus TCP server: the first request gets ``first``'s bytes, every later
    one (on any connection) a valid reply of ``values``."""

    def __init__(self, first: MakeReply, values: list[int]) -> None:
        self.first: MakeReply | None = first
        self.values = values
        self.sent: list[bytes] = []
        self.tids: list[int] = []

    async def serve(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        try:
            while True:
                header = await reader.readexactly(7)
                tid, _, length, _ = struct.unpack(">HHHB", header)
                await reader.readexactly(length - 1)
                make, self.first = self.first, None
                data = make(tid) if make else mbap(tid, values_pdu(self.values))
                self.tids.append(tid)
                self.sent.append(data)
                writer.write(data)
                await writer.drain()
        except (asyncio.IncompleteReadError, ConnectionError):
            pass
        finally:
            writer.close()


# -- an RS-485 line of ptys ------------------------------------------------------------------------


@contextlib.asynccontextmanager
async def pty_line(ports: int) -> AsyncIterator[list[str]]:
    """``ports`` pty paths joined into one RS-485 line: what is sent on one port, every
    other port receives, as every transceiver on a bus hears the line (a port does not
    hear its own bytes; collisions are not modelled). Masters and slaves of any make
    (pymodbus, drivebus, mbpoll) open the paths as serial ports."""
    loop = asyncio.get_running_loop()
    ends = [os.openpty() for _ in range(ports)]
    for master, slave in ends:
        tty.setraw(slave)
        os.set_blocking(master, False)
    masters = [m for m, _ in ends]

    def carry(src: int) -> None:
        try:
            data = os.read(src, 4096)
        except OSError:
            return  # EIO: nobody has that port open right now
        for dst in masters:
            if dst != src:
                with contextlib.suppress(OSError):  # a port nobody has open drops it
                    os.write(dst, data)

    for m in masters:
        loop.add_reader(m, carry, m)
    try:
        yield [os.ttyname(s) for _, s in ends]
    finally:
        for m in masters:
            loop.remove_reader(m)
        for m, s in ends:
            os.close(m)
            os.close(s)
