"""Networked lines: Modbus TCP (``TcpLine``) and RTU over TCP (``RtuOverTcpLine``).

Both keep one persistent connection, reconnect with backoff after the peer closes or the
network drops, and report every failure as a typed error:

* ``open()`` fails with ``LineClosed`` naming host:port and the cause;
* once open, a dropped connection fails the transactions it carried (and those issued
  while reconnecting is backing off) with ``ConnectionLost``. It is a ``TransactionError``
  on purpose: the bus scheduler treats ``LineClosed`` as "this line is gone for good"
  and stops, while a network line recovers: reads are retried and reconnect at once,
  non-idempotent writes fail to their caller, who must read back state;
* after ``close()`` every call fails with ``LineClosed``.
"""

from __future__ import annotations

import abc
import asyncio
import functools
import socket
import struct
from collections import deque
from dataclasses import dataclass
from typing import Generic, TypeVar

from drivebus.clock import monotonic
from drivebus.errors import (
    ConfigError,
    ConnectionLost,
    FrameError,
    LineClosed,
    LineConfigError,
    LineNoise,
    ResponseTimeout,
    WrongResponder,
)
from drivebus.line.base import Exchange, Line
from drivebus.line.link import RtuLink
from drivebus.line.receiver import RtuReceiver, StreamProtocol, read_waiting
from drivebus.pdu import LengthPredictor
from drivebus.settings import LineSettings
from drivebus.timing import timing

__all__ = [
    "ConnectionLost",
    "LineConfigError",
    "NetworkLine",
    "RtuOverTcpLine",
    "TcpLine",
    "TcpLineStats",
    "mbap_frame",
]

_MBAP = struct.Struct(">HHHB")  # transaction id, protocol id (0), length (unit + PDU), unit id
MAX_PDU = 253
UNSOLICITED_LIMIT = 16
"""Replies in a row that match no request (beyond ``max_in_flight`` late ones) after which
a Modbus TCP peer is taken for a babbler and the connection is dropped."""


def mbap_frame(tid: int, unit: int, pdu: bytes) -> bytes:
    """A Modbus TCP ADU: the 7-byte MBAP header followed by ``pdu``."""
    return _MBAP.pack(tid, 0, len(pdu) + 1, unit) + pdu


@dataclass
class TcpLineStats:
    """What happened to a networked line's connection."""

    connects: int = 0
    """Successful connects (the first one included)."""
    disconnects: int = 0
    """Connections lost while the line was open (peer closed, reset, stream corrupt)."""
    failed_connects: int = 0
    late_replies: int = 0
    """Replies that came after their request had timed out (or needed none), discarded."""
    rejected_replies: int = 0
    """Replies whose transaction id matched no request sent on the connection."""
    last_error: str = ""


def _cause(exc: BaseException | None) -> str:
    if exc is None:
        return "the peer closed the connection"
    text = str(exc) or "no details"
    return f"{type(exc).__name__}: {text}"


ConnectionT = TypeVar("ConnectionT", bound=StreamProtocol)
"""The protocol object one connection of a networked line runs."""


class NetworkLine(Line, Generic[ConnectionT], abc.ABC):
    """Connection handling shared by the TCP lines: connect, keepalive, reconnect backoff.

    A subclass says which protocol a connection runs (``_make_protocol``); the base hands
    back that type from ``_connection()``.
    """

    scheme = "tcp"

    def __init__(
        self,
        host: str,
        port: int,
        *,
        connect_timeout: float,
        reconnect_delay: float,
        reconnect_delay_max: float,
        connect_on_open: bool,
    ) -> None:
        if not 0 < port < 65536:
            raise ConfigError(f"TCP port {port} is outside 1..65535")
        if connect_timeout <= 0:
            raise ConfigError(f"connect_timeout must be > 0 s, not {connect_timeout}")
        if reconnect_delay < 0 or reconnect_delay_max < reconnect_delay:
            raise ConfigError(
                "reconnect delays must satisfy 0 <= reconnect_delay <= reconnect_delay_max"
            )
        self.host = host
        self.port = port
        self.name = f"{self.scheme}://{host}:{port}"
        self.connect_timeout = connect_timeout
        self.reconnect_delay = reconnect_delay
        self.reconnect_delay_max = reconnect_delay_max
        self.connect_on_open = connect_on_open
        self.stats = TcpLineStats()
        self._conn: ConnectionT | None = None
        self._connect_lock = asyncio.Lock()
        self._closed = True
        self._failures = 0
        self._next_attempt = 0.0

    # -- state --------------------------------------------------------------------------------

    @property
    def address(self) -> str:
        """``host:port`` as used in error messages."""
        return f"{self.host}:{self.port}"

    @property
    def connected(self) -> bool:
        """True while a connection is up."""
        return self._live() is not None

    @property
    def reconnect_at(self) -> float:
        """Monotonic time of the next connect attempt (when down; the past means "now")."""
        return self._next_attempt

    def _live(self) -> ConnectionT | None:
        """The current connection if it is up, else None."""
        conn = self._conn
        if (
            conn is None
            or conn.lost is not None
            or conn.transport is None
            or conn.transport.is_closing()
        ):
            return None
        return conn

    # -- life cycle ---------------------------------------------------------------------------

    async def open(self) -> None:
        """Connect (unless ``connect_on_open=False``); ``LineClosed`` names the cause."""
        self._closed = False
        self._failures = 0
        self._next_attempt = 0.0
        if self.connect_on_open:
            async with self._connect_lock:
                await self._connect()

    async def close(self) -> None:
        """Close the connection; transactions waiting on it fail with ``LineClosed``."""
        self._closed = True
        conn, self._conn = self._conn, None
        if conn is not None and conn.transport is not None:
            conn.transport.close()
            conn.connection_lost(None)  # wake waiters now; asyncio repeats it harmlessly

    @abc.abstractmethod
    def _make_protocol(self) -> ConnectionT:
        """A fresh protocol object for one connection."""

    async def _connect(self) -> ConnectionT:
        """Connect now; ``LineClosed`` naming host:port and the cause if that fails."""
        loop = asyncio.get_running_loop()
        try:
            async with asyncio.timeout(self.connect_timeout):
                _, conn = await loop.create_connection(self._make_protocol, self.host, self.port)
        except TimeoutError as exc:
            raise self._connect_failed(
                f"no answer within the connect timeout of {self.connect_timeout:g} s"
            ) from exc
        except OSError as exc:
            raise self._connect_failed(_cause(exc)) from exc
        assert conn.transport is not None
        sock = conn.transport.get_extra_info("socket")
        if sock is not None:
            sock.setsockopt(socket.SOL_SOCKET, socket.SO_KEEPALIVE, 1)
            sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        self._conn = conn
        self._failures = 0
        self.stats.connects += 1
        return conn

    def _connect_failed(self, cause: str) -> LineClosed:
        self._failures += 1
        self.stats.failed_connects += 1
        delay = min(self.reconnect_delay_max, self.reconnect_delay * 2 ** (self._failures - 1))
        self._next_attempt = monotonic() + delay
        self.stats.last_error = f"cannot connect to {self.address}: {cause}"
        return LineClosed(f"{self.name}: cannot connect to {self.address}: {cause}")

    async def _connection(self) -> ConnectionT:
        """The live connection, reconnecting if one is due; ``ConnectionLost`` otherwise."""
        if self._closed:
            raise LineClosed(f"{self.name} is closed")
        conn = self._live()
        if conn is not None:
            return conn
        async with self._connect_lock:
            if self._closed:
                raise LineClosed(f"{self.name} is closed")
            conn = self._live()
            if conn is not None:
                return conn
            wait = self._next_attempt - monotonic()
            if wait > 0:
                raise ConnectionLost(
                    f"{self.name}: not connected ({self.stats.last_error or 'down'}); "
                    f"next reconnect attempt in {wait:.3f} s"
                )
            try:
                return await self._connect()
            except LineClosed as exc:
                raise ConnectionLost(str(exc)) from exc

    def _connection_lost(self, conn: ConnectionT, exc: BaseException | None) -> None:
        """Called by the protocols: forget the connection; the next attempt is immediate."""
        if conn.lost is None:
            conn.lost = exc or ConnectionResetError("connection closed")
        if self._conn is not conn:
            return  # already forgotten (closed by us, or a repeated notification)
        self._conn = None
        if not self._closed:
            self.stats.disconnects += 1
            self.stats.last_error = f"connection to {self.address} lost: {_cause(exc)}"
            self._next_attempt = monotonic()

    def __repr__(self) -> str:
        return f"{type(self).__name__}({self.host!r}, {self.port})"


# -- Modbus TCP ---------------------------------------------------------------------------


@dataclass(slots=True)
class _Pending:
    unit: int
    future: asyncio.Future[bytes]


class _MbapProtocol(StreamProtocol):
    """One Modbus TCP connection: splits the byte stream into MBAP frames.

    Each read is parsed in one pass with bounded work: at most one reply per request in
    flight plus ``UNSOLICITED_LIMIT`` unmatched ones, or up to the first bytes that are
    not MBAP; then the connection is dropped as noisy.
    """

    def __init__(self, line: TcpLine) -> None:
        super().__init__(line.name)
        self.line = line
        self.buf = bytearray()
        self.pending: dict[int, _Pending] = {}
        self.abandoned: deque[int] = deque(maxlen=64)
        self.unsolicited = 0
        """Replies in a row that matched no waiting request."""
        self.noise = ""
        """Why the line dropped this connection as noisy ("" while it has not)."""

    def data_received(self, data: bytes) -> None:
        if self.noise:
            return  # dropped; the transport is closing
        buf = self.buf
        buf += data
        pos, end = 0, len(buf)
        limit = UNSOLICITED_LIMIT + self.line.max_in_flight
        while end - pos >= _MBAP.size:
            tid, pid, length, unit = _MBAP.unpack_from(buf, pos)
            if pid != 0 or not 2 <= length <= MAX_PDU + 1:
                header = bytes(buf[pos : pos + _MBAP.size]).hex(" ")
                self.line._noisy_stream(self, f"not a Modbus TCP header: {header}")
                return
            frame_end = pos + 6 + length
            if frame_end > end:
                break
            pdu = bytes(buf[pos + _MBAP.size : frame_end])
            pos = frame_end
            if self.line._on_reply(self, tid, unit, pdu):
                self.unsolicited = 0
                continue
            self.unsolicited += 1
            if self.unsolicited > limit:
                self.line._noisy_stream(
                    self, f"{self.unsolicited} replies in a row match no request"
                )
                return
        del buf[:pos]

    def connection_lost(self, exc: Exception | None) -> None:
        self.line._connection_lost(self, exc)


class TcpLine(NetworkLine[_MbapProtocol]):
    """A Modbus TCP connection to one device or gateway (MBAP framing, transaction ids).

    One request is in flight at a time by default; ``max_in_flight`` allows more on
    devices that pipeline (replies are matched by transaction id, in any order).
    ``drop_after_timeouts`` consecutive timeouts close the connection (a half-open TCP
    connection never reports itself) so that the next request reconnects; 0 disables it.
    An ``Exchange``'s ``wire_time`` is the round trip: the time the connection was busy.
    """

    counts_garbage = True
    unit_ids = range(0, 256)

    def __init__(
        self,
        host: str,
        port: int = 502,
        *,
        connect_timeout: float = 3.0,
        max_in_flight: int = 1,
        reconnect_delay: float = 0.1,
        reconnect_delay_max: float = 5.0,
        drop_after_timeouts: int = 3,
        connect_on_open: bool = True,
    ) -> None:
        super().__init__(
            host,
            port,
            connect_timeout=connect_timeout,
            reconnect_delay=reconnect_delay,
            reconnect_delay_max=reconnect_delay_max,
            connect_on_open=connect_on_open,
        )
        if max_in_flight < 1:
            raise ConfigError(f"max_in_flight must be >= 1, not {max_in_flight}")
        if drop_after_timeouts < 0:
            raise ConfigError("drop_after_timeouts must be >= 0")
        self.settings = None
        self.max_in_flight = max_in_flight
        self.drop_after_timeouts = drop_after_timeouts
        self._slots = asyncio.Semaphore(max_in_flight)
        self._tid = 0
        self._timeouts_in_row = 0
        self._garbage_bytes = 0

    @property
    def garbage_bytes(self) -> int:
        """Bytes discarded with streams dropped as junk (not Modbus TCP, or a babbler)."""
        return self._garbage_bytes

    def _make_protocol(self) -> _MbapProtocol:
        return _MbapProtocol(self)

    def _next_tid(self, conn: _MbapProtocol) -> int:
        for _ in range(0x10000):
            self._tid = (self._tid + 1) & 0xFFFF
            if self._tid not in conn.pending:
                return self._tid
        raise AssertionError("no free transaction id")  # at most max_in_flight are in use

    async def transact(
        self,
        unit: int,
        pdu: bytes,
        *,
        expect: LengthPredictor | None,
        settings: LineSettings | None = None,
        timeout: float = 0.1,
        quiet_by: float | None = None,
    ) -> Exchange:
        """Send ``pdu`` to ``unit`` and await the reply with the same transaction id.

        A TCP connection keeps no silences: ``quiet_by`` does not apply; junk from the
        peer fails the requests in flight with ``LineNoise`` and drops the connection.
        """
        if settings is not None:
            raise LineConfigError(
                f"{self.name} is Modbus TCP: slave {unit} cannot have serial settings",
                slave=unit,
            )
        if not 0 <= unit <= 255 or not 1 <= len(pdu) <= MAX_PDU:
            raise LineConfigError(
                f"{self.name}: unit {unit} / PDU of {len(pdu)} bytes cannot be sent "
                f"(unit 0..255, PDU 1..{MAX_PDU} bytes)",
                slave=unit,
            )
        async with self._slots:
            conn = await self._connection()
            if conn.buf and not conn.pending:
                # Bytes left over from an earlier exchange (trailing junk, half a late
                # frame): the stream is out of step. Start this request on a fresh one.
                self._noisy_stream(conn, "bytes left over from an earlier reply")
                conn = await self._connection()
            return await self._exchange(conn, unit, pdu, expect, timeout)

    async def _exchange(
        self,
        conn: _MbapProtocol,
        unit: int,
        pdu: bytes,
        expect: LengthPredictor | None,
        timeout: float,
    ) -> Exchange:
        loop = asyncio.get_running_loop()
        tid = self._next_tid(conn)
        adu = mbap_frame(tid, unit, pdu)
        tx = monotonic()
        if expect is None:
            conn.abandoned.append(tid)  # whatever comes back is not awaited
            conn.send(adu)
            return Exchange(b"", tx, tx, tx, len(adu), 0, 0.0)
        fut: asyncio.Future[bytes] = loop.create_future()
        conn.pending[tid] = _Pending(unit, fut)
        handle = loop.call_later(timeout, self._expire, conn, tid, unit, timeout)
        try:
            conn.send(adu)
            reply = await fut
        finally:
            handle.cancel()
            conn.pending.pop(tid, None)
            if not fut.done() or fut.cancelled() or fut.exception() is not None:
                conn.abandoned.append(tid)
        self._timeouts_in_row = 0
        rx = monotonic()
        self._check_length(unit, reply, expect)
        n = _MBAP.size + len(reply)
        return Exchange(reply, tx, tx, rx, len(adu), n, rx - tx)

    def _check_length(self, unit: int, reply: bytes, expect: LengthPredictor) -> None:
        if expect(reply) != len(reply):
            raise FrameError(
                f"slave {unit} on {self.name}: malformed reply PDU {reply[:32].hex(' ')}",
                slave=unit,
            )

    def _expire(self, conn: _MbapProtocol, tid: int, unit: int, timeout: float) -> None:
        p = conn.pending.get(tid)
        if p is None or p.future.done():
            return
        p.future.set_exception(
            ResponseTimeout(
                f"slave {unit} on {self.name}: no reply within {timeout * 1000:.0f} ms "
                f"(transaction id {tid})",
                slave=unit,
            )
        )
        self._timeouts_in_row += 1
        if conn.buf and conn.transport is not None:
            # Part of a frame is left over: the stream is out of step, and the next reply
            # would be read behind those bytes. A fresh connection starts clean.
            self._timeouts_in_row = 0
            conn.transport.close()
            return
        if self.drop_after_timeouts and self._timeouts_in_row >= self.drop_after_timeouts:
            self._timeouts_in_row = 0
            if conn.transport is not None:
                conn.transport.close()  # half-open? reconnect on the next request

    # -- called by the protocol -----------------------------------------------------------------

    def _on_reply(self, conn: _MbapProtocol, tid: int, unit: int, pdu: bytes) -> bool:
        """Hand a reply to the request waiting for it; False if none was (late, unknown)."""
        p = conn.pending.get(tid)
        if p is not None and not p.future.done():
            if unit != p.unit:
                p.future.set_exception(
                    WrongResponder(
                        f"slave {p.unit} on {self.name}: reply (transaction id {tid}) "
                        f"came from unit {unit}",
                        slave=p.unit,
                        responder=unit,
                    )
                )
            else:
                p.future.set_result(pdu)
            return True
        if tid in conn.abandoned:
            self.stats.late_replies += 1
            return False
        self.stats.rejected_replies += 1
        waiting = [q for q in conn.pending.values() if not q.future.done()]
        msg = f"{self.name}: reply with transaction id {tid} matches no request"
        self.stats.last_error = msg
        if len(waiting) == 1:
            # One request in flight: the peer answered it with a wrong id. Reject the reply.
            q = waiting[0]
            wanted = next(t for t, v in conn.pending.items() if v is q)
            q.future.set_exception(
                FrameError(f"{msg} (expected {wanted}): reply rejected", slave=q.unit)
            )
        # With several in flight the reply cannot be attributed: they time out instead.
        return False

    def _noisy_stream(self, conn: _MbapProtocol, cause: str) -> None:
        """Junk from the peer: the stream is out of step; fail what is in flight with
        ``LineNoise`` and drop the connection (the next request reconnects)."""
        msg = f"{self.name}: {cause}; the peer sends junk, reconnecting"
        self.stats.last_error = msg
        conn.noise = msg
        self._garbage_bytes += len(conn.buf)
        conn.buf.clear()
        for p in conn.pending.values():
            if not p.future.done():
                p.future.set_exception(self._noise_error(conn, p.unit))
        if conn.transport is not None:
            conn.transport.close()

    def _noise_error(self, conn: _MbapProtocol, unit: int) -> LineNoise:
        return LineNoise(f"slave {unit} on {conn.noise}", slave=unit, line=self.name)

    def _connection_lost(self, conn: _MbapProtocol, exc: BaseException | None) -> None:
        super()._connection_lost(conn, exc)
        for p in conn.pending.values():
            if p.future.done():
                continue
            if self._closed:
                err: Exception = LineClosed(f"{self.name} closed")
            elif conn.noise:
                err = self._noise_error(conn, p.unit)
            else:
                err = ConnectionLost(
                    f"slave {p.unit} on {self.name}: connection to {self.address} lost "
                    f"while waiting for the reply ({_cause(exc)})",
                    slave=p.unit,
                )
            p.future.set_exception(err)


# -- RTU over TCP -------------------------------------------------------------------------


class _RtuTcpReceiver(RtuReceiver):
    """RtuReceiver on a TCP socket that tells its line when the connection drops."""

    def __init__(self, line: RtuOverTcpLine) -> None:
        super().__init__(line.name)
        self.line = line
        self.cause = ""

    def connection_made(self, transport: asyncio.BaseTransport) -> None:
        super().connection_made(transport)
        sock = transport.get_extra_info("socket")
        if sock is not None:
            self.pending_bytes = functools.partial(read_waiting, sock.fileno())

    def connection_lost(self, exc: Exception | None) -> None:
        if not self.cause:
            self.cause = _cause(exc)
        super().connection_lost(exc)
        self.line._connection_lost(self, exc)


class RtuOverTcpLine(NetworkLine[_RtuTcpReceiver]):
    """RTU frames through a transparent serial device server (an RS-485 line over TCP).

    ``settings`` are those of the server's serial port: the silences (t3.5) are computed
    from them. The port has one setting, so per-slave settings are refused. When no reply
    marks the end of the traffic (broadcast, timeout, dropped connection) the silence is
    counted from the estimated end of the request plus ``latency``, an allowance for the
    network delay before the server's UART started sending it.
    """

    scheme = "rtu+tcp"
    counts_garbage = True
    waits_for_silence = True
    settings: LineSettings

    def __init__(
        self,
        host: str,
        port: int,
        settings: LineSettings | None = None,
        *,
        connect_timeout: float = 3.0,
        reconnect_delay: float = 0.1,
        reconnect_delay_max: float = 5.0,
        broadcast_delay: float = 0.1,
        latency: float = 0.001,
        connect_on_open: bool = True,
    ) -> None:
        super().__init__(
            host,
            port,
            connect_timeout=connect_timeout,
            reconnect_delay=reconnect_delay,
            reconnect_delay_max=reconnect_delay_max,
            connect_on_open=connect_on_open,
        )
        if broadcast_delay < 0 or latency < 0:
            raise ConfigError("broadcast_delay and latency must be >= 0 seconds")
        self.settings = settings or LineSettings()
        self.broadcast_delay = broadcast_delay
        self._lock = asyncio.Lock()
        self._link = RtuLink(latency=latency)

    def _make_protocol(self) -> _RtuTcpReceiver:
        return _RtuTcpReceiver(self)

    @property
    def garbage_bytes(self) -> int:
        """Bytes received outside any reply on the current connection, discarded."""
        return self._conn.garbage_bytes if self._conn is not None else 0

    def last_activity(self) -> float:
        """When the last frame sent or byte received (on this connection) ended."""
        return self._link.last_activity(self._conn)

    def ready_at(self, settings: LineSettings | None) -> float:
        """When t3.5 at the serial port's settings will have passed since the last traffic."""
        return self._link.ready_at(self._conn, timing(self.settings).t35)

    async def close(self) -> None:
        """Close the connection and release the silence timer."""
        await super().close()
        self._link.close()

    def withdraw(self) -> bool:
        """Take back the request waiting for its silence, if its frame is not out yet."""
        return self._link.withdraw()

    async def transact(
        self,
        unit: int,
        pdu: bytes,
        *,
        expect: LengthPredictor | None,
        settings: LineSettings | None = None,
        timeout: float = 0.1,
        quiet_by: float | None = None,
        withdrawable: bool = False,
    ) -> Exchange:
        """Send one RTU frame after t3.5 of silence and read its reply by length
        (``LineNoise`` if the line is not quiet by ``quiet_by``)."""
        if settings is not None and settings != self.settings:
            raise LineConfigError(
                f"slave {unit} on {self.name}: settings {settings} differ from the serial "
                f"server's port ({self.settings}); its port has one setting for all slaves",
                slave=unit,
            )
        async with self._lock:
            rx = await self._connection()
            if quiet_by is None:
                quiet_by = monotonic() + timeout
            try:
                return await self._exchange(rx, unit, pdu, expect, timeout, quiet_by,
                                            withdrawable)
            except LineClosed as exc:
                if self._closed:
                    raise
                raise ConnectionLost(
                    f"slave {unit} on {self.name}: connection to {self.address} lost "
                    f"while waiting for the reply ({rx.cause or 'connection closed'})",
                    slave=unit,
                ) from exc

    async def _exchange(
        self,
        rx: _RtuTcpReceiver,
        unit: int,
        pdu: bytes,
        expect: LengthPredictor | None,
        timeout: float,
        quiet_by: float,
        withdrawable: bool,
    ) -> Exchange:
        tm = timing(self.settings)
        return await self._link.transact(
            rx,
            rx.send,
            unit,
            pdu,
            expect,
            tm,
            silence=tm.t35,
            quiet_by=quiet_by,
            timeout=timeout,
            broadcast_delay=self.broadcast_delay,
            withdrawable=withdrawable,
        )

    def __repr__(self) -> str:
        return f"RtuOverTcpLine({self.host!r}, {self.port}, {self.settings})"
