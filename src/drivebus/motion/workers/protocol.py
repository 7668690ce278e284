"""What a machine and its worker processes say to each other, and how it is framed.

One Unix stream socket per worker. Each message is a tuple (its tag first), pickled and
sent with a 4-byte length in front; messages queued in one turn of the event loop leave in
one write. Both ends are this package's own processes (a worker is started by its machine
and hears nothing else), so pickle carries the line configs, the replies and the
statistics as they are. Errors cross as (class, message, attributes) and come back as the
same typed ``DrivebusError``.

From the machine: ``OPEN`` (the lines to serve), ``HANDLE`` (a slave handle's settings),
``FORGET`` (a handle gone), ``EXPECT`` (a reply-length function), ``TX`` (a transaction),
``CANCEL`` (its caller gave up), ``HOLD``/``UNHOLD`` (``Bus.hold``), ``HOLD_NOW``
(``Bus.hold_now``, let go by ``UNHOLD``), ``OBSERVE`` (send a line's transactions),
``CLOSE``. From a worker: ``READY``, ``OK``/``ERR`` (a transaction's
reply or error), ``CANCELLED`` (what became of a cancelled one), ``HELD``, ``STATS``,
``SEEN`` (observed transactions), ``LOG`` (its log records), ``CLOSED``, and ``ALIVE``
every ``ALIVE_PERIOD`` (the machine's watchdog: a worker it has not heard from for
``WATCHDOG`` is taken for hung and killed).
"""

from __future__ import annotations

import asyncio
import importlib
import pickle
import struct
from collections.abc import Callable
from typing import Any

from drivebus.errors import DrivebusError, TransactionError

__all__ = [
    "ALIVE",
    "ALIVE_PERIOD",
    "CANCEL",
    "CANCELLED",
    "CLOSE",
    "CLOSED",
    "ERR",
    "EXPECT",
    "FORGET",
    "HANDLE",
    "HELD",
    "HOLD",
    "HOLD_NOW",
    "LOG",
    "OBSERVE",
    "OK",
    "OPEN",
    "READY",
    "SEEN",
    "STATS",
    "TAKEN",
    "TX",
    "UNHOLD",
    "WATCHDOG",
    "Channel",
    "decode_error",
    "encode_error",
]

OPEN, HANDLE, EXPECT, TX, CANCEL, HOLD, UNHOLD, OBSERVE, CLOSE, FORGET, HOLD_NOW = range(11)
READY, OK, ERR, CANCELLED, HELD, STATS, SEEN, LOG, CLOSED, TAKEN, ALIVE = range(100, 111)
"""``TAKEN, line, when``: the worker queued an emergency request on that line (a stop) at
``when`` (``time.monotonic``, the host's clock): where the stop's own scheduling begins."""

ALIVE_PERIOD = 0.2
"""How often a serving worker says it is alive, seconds."""
WATCHDOG = 1.5
"""How long the machine goes without a word from a serving worker before it kills it
(hung, or stopped: its lines' stops could not leave) and starts it again, seconds: some
seven periods, so that a worker starved of the CPU for a moment is not taken for hung."""

_LENGTH = struct.Struct("<I")
_MAX_MESSAGE = 64 << 20
"""The longest message either end accepts (a statistics snapshot is some kilobytes)."""


def encode_error(exc: BaseException) -> tuple[str, str, str, dict[str, Any]]:
    """An error as (module, class name, message, attributes) for the other process."""
    attrs: dict[str, Any] = {}
    for key, value in getattr(exc, "__dict__", {}).items():
        try:
            pickle.dumps(value)
        except Exception:
            continue
        attrs[key] = value
    cls = type(exc)
    return cls.__module__, cls.__qualname__, str(exc), attrs


def decode_error(spec: tuple[str, str, str, dict[str, Any]]) -> DrivebusError:
    """The typed error ``encode_error`` described (a ``TransactionError`` with its text if
    its class is not one of drivebus's errors)."""
    module, name, message, attrs = spec
    cls: Any = None
    if module.startswith("drivebus."):
        try:
            cls = getattr(importlib.import_module(module), name)
        except (ImportError, AttributeError):
            cls = None
    if not (isinstance(cls, type) and issubclass(cls, DrivebusError)):
        return TransactionError(f"{name}: {message}")
    exc = cls.__new__(cls)
    Exception.__init__(exc, message)
    exc.__dict__.update(attrs)
    return exc


class Channel(asyncio.Protocol):
    """One end of a machine-worker socket: ``send`` queues a message (written at the end
    of the loop's turn, with the others of that turn), ``on_message`` hears each one."""

    def __init__(self, on_message: Callable[[tuple[Any, ...]], None],
                 on_lost: Callable[[BaseException | None], None]) -> None:
        self.on_message = on_message
        self.on_lost = on_lost
        self.transport: asyncio.Transport | None = None
        self.closed = False
        self._out: list[bytes] = []
        self._buf = bytearray()
        self._flushing = False

    def connection_made(self, transport: asyncio.BaseTransport) -> None:
        assert isinstance(transport, asyncio.Transport)
        self.transport = transport

    def connection_lost(self, exc: Exception | None) -> None:
        self.closed = True
        self.on_lost(exc)

    def send(self, message: tuple[Any, ...]) -> None:
        """Queue ``message``; it leaves at the end of this turn of the loop."""
        if self.closed or self.transport is None:
            return
        data = pickle.dumps(message, pickle.HIGHEST_PROTOCOL)
        self._out.append(_LENGTH.pack(len(data)))
        self._out.append(data)
        if not self._flushing:
            # (the flush scheduled before it is marked: called with no loop running, it
            # raises here and the next send schedules it, not leaves it never scheduled)
            asyncio.get_running_loop().call_soon(self._flush)
            self._flushing = True

    def send_now(self, message: tuple[Any, ...]) -> None:
        """Send ``message`` at once, with whatever is queued before it (a stop: it does
        not wait for the end of this turn of the loop)."""
        self.send(message)
        self._flush()

    def _flush(self) -> None:
        self._flushing = False
        out, self._out = self._out, []
        if out and self.transport is not None and not self.closed:
            self.transport.write(b"".join(out))

    def data_received(self, data: bytes) -> None:
        buf = self._buf
        buf += data
        start = 0
        end = len(buf)
        unpack = _LENGTH.unpack_from
        while end - start >= 4:
            (n,) = unpack(buf, start)
            if n > _MAX_MESSAGE:
                self.closed = True
                if self.transport is not None:
                    self.transport.abort()
                return
            if end - start - 4 < n:
                break
            message = pickle.loads(buf[start + 4:start + 4 + n])
            start += 4 + n
            self.on_message(message)
        del buf[:start]

    def close(self) -> None:
        """Write what is queued and close the socket."""
        self._flush()
        if self.transport is not None:
            self.transport.close()
