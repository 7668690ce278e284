"""Babbling devices: junk bytes put on a simulated line without pause.

A device at the wrong baud rate, a broken transmitter stuck on, a cable picking up noise,
or a network peer that is not Modbus at all: from the master's side the line never goes
quiet. ``babble_paced`` emits junk at a line's character rate in chunks closer together
than t1.5, so the wire is continuously busy; ``babble_flat_out`` emits it as fast as the
medium takes it (a pty or a socket faster than any line). The front-ends (``VirtualWire``,
``SimSerialServer``, ``SimTcpServer``) offer them as ``babbling()`` context managers.
"""

from __future__ import annotations

import random
from collections.abc import Awaitable, Callable

from drivebus.clock import PreciseTimer, monotonic
from drivebus.timing import Timing

__all__ = ["CHUNK", "JunkStream", "babble_flat_out", "babble_paced"]

CHUNK = 4096
"""Bytes offered to the medium at once when babbling flat out."""


class JunkStream:
    """Reproducible junk bytes, handed out in pieces of any size."""

    def __init__(self, seed: int = 0, size: int = 65536) -> None:
        rng = random.Random(seed)
        self._block = rng.randbytes(size)
        self._pos = 0
        self.total = 0
        """Bytes handed out so far."""

    def take(self, n: int) -> bytes:
        """The next ``n`` junk bytes."""
        out = bytearray()
        while len(out) < n:
            piece = self._block[self._pos : self._pos + n - len(out)]
            out += piece
            self._pos = (self._pos + len(piece)) % len(self._block)
        self.total += n
        return bytes(out)


async def babble_paced(
    emit: Callable[[bytes], Awaitable[None]], tm: Timing, *, seed: int = 0
) -> None:
    """Emit junk for ever at one byte per character time of ``tm``, in chunks at most
    t1.5 / 2 apart: the line is never quiet for a character and a half."""
    junk = JunkStream(seed)
    tick = max(tm.t15 / 2, 0.25e-3)
    timer = PreciseTimer()
    try:
        start = monotonic()
        while True:
            await timer.sleep_until(monotonic() + tick)  # late wake-ups catch up below
            due = int((monotonic() - start) / tm.char_time) - junk.total
            if due > 0:
                await emit(junk.take(due))
    finally:
        timer.close()


async def babble_flat_out(emit: Callable[[bytes], Awaitable[None]], *, seed: int = 0) -> None:
    """Emit junk for ever, as fast as ``emit`` takes it (``emit`` waits for the medium
    to take more, so this yields between chunks)."""
    junk = JunkStream(seed)
    while True:
        await emit(junk.take(CHUNK))
