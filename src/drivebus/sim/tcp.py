"""Simulated networked devices on loopback: a Modbus TCP server and a serial device server.

* ``SimTcpServer`` serves ``SimSlave`` objects as Modbus TCP units (MBAP framing), like a
  networked drive or a TCP gateway;
* ``SimSerialServer`` is a transparent serial server (RTU over TCP): the bytes a client
  sends go out on a simulated RS-485 line at the port's settings, taking wire time, and
  the slaves' replies come back after their turnaround and wire time. The line is a
  ``Segment``, the model behind ``VirtualWire`` too: frames are logged with the silence
  before them.

Both are async context managers that own their tasks in an anyio task group, listen on
127.0.0.1 at an ephemeral port (``.port``), and offer fault hooks for tests: close the
connection instead of answering the next request(s), answer with a wrong transaction id,
plus the slaves' own ``FaultPlan`` faults; and ``babbling()``, junk sent without pause to
every client.
"""

from __future__ import annotations

import contextlib
import math
import socket
import struct
from collections.abc import AsyncIterator, Awaitable, Callable, Iterable, Iterator
from dataclasses import dataclass, field
from types import TracebackType

import anyio
import anyio.abc
from anyio.abc import SocketAttribute

from drivebus.clock import monotonic
from drivebus.line.tcp import mbap_frame
from drivebus.settings import LineSettings
from drivebus.sim.noise import babble_flat_out, babble_paced
from drivebus.sim.segment import Segment, SegmentView, add_slave
from drivebus.sim.slave import Fault, SimSlave
from drivebus.tasks import ServiceTasks
from drivebus.timing import timing

__all__ = ["ServerFaults", "SimSerialServer", "SimTcpServer", "TcpRequest"]

_MBAP = struct.Struct(">HHHB")
_GONE = (anyio.BrokenResourceError, anyio.ClosedResourceError, anyio.EndOfStream, OSError)
"""What a send or receive raises once the client has gone: the connection just ends."""


@dataclass
class ServerFaults:
    """Server-level faults for the next requests (slave-level ones live in ``FaultPlan``)."""

    drop: int = 0
    """Close the connection instead of answering the next ``drop`` requests."""
    reset: bool = False
    """Drop with a TCP reset (SO_LINGER 0) rather than an orderly close."""
    wrong_tid: int = 0
    """Answer the next ``wrong_tid`` requests with another transaction id (Modbus TCP)."""

    def take_drop(self) -> bool:
        """True if this request's connection is to be dropped (counting down)."""
        if self.drop > 0:
            self.drop -= 1
            return True
        return False

    def take_wrong_tid(self) -> bool:
        """True if this reply is to carry a wrong transaction id (counting down)."""
        if self.wrong_tid > 0:
            self.wrong_tid -= 1
            return True
        return False


@dataclass(eq=False)
class _Client:
    """One accepted connection: its stream, a send lock and the scope to drop it."""

    number: int
    stream: anyio.abc.SocketStream
    scope: anyio.CancelScope
    send_lock: anyio.Lock = field(default_factory=anyio.Lock)
    outstanding: int = 0
    """Requests received on this connection and not yet answered."""

    async def send(self, data: bytes) -> bool:
        """Send ``data``; False if the client has gone."""
        try:
            async with self.send_lock:
                await self.stream.send(data)
        except _GONE:
            return False
        return True

    async def receive(self) -> bytes:
        """The next bytes from the client; empty once it has gone."""
        try:
            return await self.stream.receive()
        except _GONE:
            return b""

    def drop(self, *, reset: bool = False) -> None:
        """Close this connection now (the handler task ends and closes the stream)."""
        if reset:
            sock = self.stream.extra(SocketAttribute.raw_socket)
            sock.setsockopt(socket.SOL_SOCKET, socket.SO_LINGER, struct.pack("ii", 1, 0))
        self.scope.cancel()


@dataclass(eq=False)
class TcpRequest:
    """One request as a simulated server received it, and what became of it."""

    client: int
    tid: int
    unit: int
    pdu: bytes
    received: float
    replied: float | None = None
    note: str = ""


class _SimServer:
    """Listener, task group, client tracking and fault hooks shared by both servers."""

    kind = "server"

    def __init__(self, slaves: Iterable[SimSlave], *, host: str, port: int) -> None:
        self.host = host
        self.port = port
        self.slaves: dict[int, SimSlave] = {}
        for s in slaves:
            self.attach(s)
        self.faults = ServerFaults()
        self.accepted = 0
        """Connections accepted so far."""
        self.received = 0
        """Requests received so far."""
        self._clients: dict[int, _Client] = {}
        self._listener: anyio.abc.Listener[anyio.abc.SocketStream] | None = None
        self._tg: anyio.abc.TaskGroup | None = None
        self._changed = anyio.Event()

    def attach(self, slave: SimSlave) -> SimSlave:
        """Serve ``slave`` at its address, which must be free."""
        return add_slave(self.slaves, slave, f"this {self.kind}")

    # -- life cycle ---------------------------------------------------------------------------

    async def __aenter__(self) -> _SimServer:
        listener = await anyio.create_tcp_listener(local_host=self.host, local_port=self.port)
        self._listener = listener
        self.port = listener.extra(SocketAttribute.local_port)
        self._tg = ServiceTasks()  # keeps answering while its users clean up
        await self._tg.__aenter__()
        self._tg.start_soon(listener.serve, self._handle, self._tg, name=f"sim {self.kind}")
        self._start_tasks(self._tg)
        return self

    async def __aexit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> bool | None:
        assert self._tg is not None and self._listener is not None
        try:
            return await self._tg.__aexit__(exc_type, exc, tb)
        finally:
            with anyio.CancelScope(shield=True):
                await self._listener.aclose()
            self._stopped()

    def _start_tasks(self, tg: anyio.abc.TaskGroup) -> None:
        """Start the server's own background tasks (none by default)."""

    def _stopped(self) -> None:
        """Release resources after the task group has ended."""

    # -- connections -----------------------------------------------------------------------------

    @property
    def connections(self) -> int:
        """Connections open right now."""
        return len(self._clients)

    def disconnect_all(self, *, reset: bool = False) -> None:
        """Close every open connection now (a network drop, as the clients see it)."""
        for c in list(self._clients.values()):
            c.drop(reset=reset)

    def drop_next(self, times: int = 1, *, reset: bool = False) -> None:
        """Close the connection instead of answering the next ``times`` requests."""
        self.faults.drop += times
        self.faults.reset = reset

    async def _handle(self, stream: anyio.abc.SocketStream) -> None:
        self.accepted += 1
        with anyio.CancelScope() as scope:
            client = _Client(self.accepted, stream, scope)
            self._clients[client.number] = client
            self._notify()
            try:
                async with stream:
                    await self._serve(client)
            finally:
                self._clients.pop(client.number, None)
                self._closed_client(client)
                self._notify()

    def _closed_client(self, client: _Client) -> None:
        """Account for a connection that has ended."""

    async def _serve(self, client: _Client) -> None:
        """Serve one connection until the client goes (``client.receive()`` is empty)."""
        raise NotImplementedError

    def _notify(self) -> None:
        self._changed.set()
        self._changed = anyio.Event()

    async def wait_requests(self, n: int) -> None:
        """Return once ``n`` requests in all have been received (tests synchronise on it)."""
        while self.received < n:
            await self._changed.wait()

    def _count_request(self) -> None:
        self.received += 1
        self._notify()

    # -- noise -----------------------------------------------------------------------------------

    @contextlib.asynccontextmanager
    async def _babbling(
        self, babble: Callable[[Callable[[bytes], Awaitable[None]]], Awaitable[None]]
    ) -> AsyncIterator[None]:
        """Run ``babble(emit)`` while inside; ``emit`` gives junk to every client."""
        async def run() -> None:
            await babble(self._to_every_client)

        async with anyio.create_task_group() as tg:
            tg.start_soon(run, name=f"sim {self.kind} babbler")
            try:
                yield
            finally:
                tg.cancel_scope.cancel()

    async def _to_every_client(self, data: bytes) -> None:
        """Send ``data`` to every connected client (wait for one if there is none)."""
        clients = list(self._clients.values())
        if not clients:
            await self._changed.wait()
            return
        self._noted_noise(len(data))
        for c in clients:
            await c.send(data)

    def _noted_noise(self, nbytes: int) -> None:
        """Account for ``nbytes`` of junk about to go out (the serial server's wire)."""


class SimTcpServer(_SimServer):
    """A Modbus TCP server for simulated slaves: ``async with SimTcpServer([...]) as srv``.

    Each connection answers its requests in order, after the slave's turnaround; with
    ``pipelined=True`` it answers concurrently (replies may overtake one another). A
    request to a unit with no slave gets exception 0x0B, as from a gateway. Unit 0 is a
    broadcast: every slave acts, nobody answers. Slave faults: NO_REPLY and POWER_LOSS
    (no reply), SLOW_REPLY, WRONG_ADDRESS (another unit id), GARBAGE (junk before the
    reply: the stream loses step). CRC_DAMAGE does not apply to TCP.
    """

    kind = "Modbus TCP server"

    def __init__(
        self,
        slaves: Iterable[SimSlave],
        *,
        host: str = "127.0.0.1",
        port: int = 0,
        pipelined: bool = False,
    ) -> None:
        super().__init__(slaves, host=host, port=port)
        self.pipelined = pipelined
        self.log: list[TcpRequest] = []
        self.outstanding = 0
        """Requests received and not yet answered (or dropped), all connections."""
        self.max_outstanding = 0
        self.noise_bytes = 0
        """Junk bytes sent by ``babbling()`` so far (to each client)."""
        self._held_units: set[int] = set()
        self._released = anyio.Event()

    async def __aenter__(self) -> SimTcpServer:
        await super().__aenter__()
        return self

    def babbling(self) -> contextlib.AbstractAsyncContextManager[None]:
        """While inside, every connection gets junk (not Modbus TCP) without pause, as
        fast as it takes it: a peer that is no Modbus device, or one gone mad."""
        return self._babbling(babble_flat_out)

    def _noted_noise(self, nbytes: int) -> None:
        self.noise_bytes += nbytes

    @contextlib.contextmanager
    def holding_replies(self, *units: int) -> Iterator[None]:
        """While inside, replies to ``units`` wait (their requests still arrive and count
        as outstanding): a test fills a client's pipeline and keeps it full. On leaving,
        the held replies go out."""
        held = set(units) - self._held_units
        self._held_units |= held
        try:
            yield
        finally:
            self._held_units -= held
            self._released.set()
            self._released = anyio.Event()

    async def wait_outstanding(self, n: int) -> None:
        """Return once at least ``n`` requests are outstanding (tests synchronise on it)."""
        while self.outstanding < n:
            await self._changed.wait()

    async def _serve(self, client: _Client) -> None:
        send, receive = anyio.create_memory_object_stream[TcpRequest](math.inf)
        buf = bytearray()
        async with anyio.create_task_group() as tg, send, receive:
            tg.start_soon(self._answer_loop, client, receive.clone(), tg)
            while data := await client.receive():
                buf += data
                now = monotonic()
                for req in self._parse(buf, client.number, now):
                    if self.faults.take_drop():
                        req.note = "connection dropped"
                        client.drop(reset=self.faults.reset)
                        return
                    self._begin(client)
                    send.send_nowait(req)

    def _parse(self, buf: bytearray, client: int, now: float) -> list[TcpRequest]:
        out = []
        while len(buf) >= _MBAP.size:
            tid, _pid, length, unit = _MBAP.unpack_from(buf)
            if len(buf) < 6 + length:
                break
            out.append(TcpRequest(client, tid, unit, bytes(buf[_MBAP.size : 6 + length]), now))
            del buf[: 6 + length]
        for req in out:
            self.log.append(req)
            self._count_request()
        return out

    def _begin(self, client: _Client) -> None:
        client.outstanding += 1
        self.outstanding += 1
        self.max_outstanding = max(self.max_outstanding, self.outstanding)
        self._notify()

    def _closed_client(self, client: _Client) -> None:
        self.outstanding -= client.outstanding  # requests it left unanswered
        client.outstanding = 0

    async def _answer_loop(
        self,
        client: _Client,
        receive: anyio.abc.ObjectReceiveStream[TcpRequest],
        tg: anyio.abc.TaskGroup,
    ) -> None:
        async with receive:
            async for req in receive:
                if self.pipelined:
                    tg.start_soon(self._answer, client, req)
                else:
                    await self._answer(client, req)

    async def _answer(self, client: _Client, req: TcpRequest) -> None:
        try:
            reply = await self._reply_for(req)
            while req.unit in self._held_units:
                await self._released.wait()
            if reply is not None and await client.send(reply):
                req.replied = monotonic()
        finally:
            if client.outstanding > 0:
                client.outstanding -= 1
                self.outstanding -= 1

    async def _reply_for(self, req: TcpRequest) -> bytes | None:
        """The ADU answering ``req`` after the slave's delay; None for no answer."""
        if req.unit == 0:
            for sl in self.slaves.values():
                if sl.powered:
                    sl.handle_pdu(req.pdu, req.received)
            req.note = "broadcast"
            return None
        slave = self.slaves.get(req.unit)
        if slave is None:
            req.note = "no slave: gateway exception"
            return mbap_frame(req.tid, req.unit, bytes((req.pdu[0] | 0x80, 0x0B)))
        faults = slave.faults.take()
        if Fault.NO_REPLY in faults or not slave.powered:
            req.note = "no reply"
            return None
        reply = slave.handle_pdu(req.pdu, req.received)
        await anyio.sleep(slave.turnaround + float(faults.get(Fault.SLOW_REPLY) or 0.0))  # type: ignore[arg-type]
        if reply is None:
            req.note = "no reply"
            return None
        return self._frame_reply(req, slave, reply, faults)

    def _frame_reply(
        self,
        req: TcpRequest,
        slave: SimSlave,
        reply: bytes,
        faults: dict[Fault, float | int | bytes | None],
    ) -> bytes:
        tid, unit = req.tid, req.unit
        if self.faults.take_wrong_tid():
            tid ^= 0x8000
            req.note = f"answered with transaction id {tid}"
        if Fault.WRONG_ADDRESS in faults:
            unit = int(faults[Fault.WRONG_ADDRESS] or (slave.address % 247) + 1)  # type: ignore[arg-type]
            req.note = f"answered as unit {unit}"
        adu = mbap_frame(tid, unit, reply)
        if Fault.GARBAGE in faults:
            junk = faults[Fault.GARBAGE]
            adu = (junk if isinstance(junk, bytes) else bytes((0xFF, 0x00, 0x55))) + adu
            req.note = "garbage before the reply"
        return adu


class SimSerialServer(SegmentView, _SimServer):
    """A transparent serial device server with simulated slaves on its RS-485 port.

    ``settings`` are the serial port's. Bytes from a client are transmitted back to back
    at those settings (a frame of n bytes takes n character times); a slave answers only
    frames at its own settings, after its turnaround, and its reply takes wire time before
    the server forwards it to the client that sent the request. ``log`` holds every frame
    with the silence before it; a request that follows the previous frame by less than
    t3.5 is a violation, and the slaves ignore it. The wire is a ``Segment``, as behind
    ``VirtualWire``: slave faults work the same, and ``log``, ``violations``,
    ``requests()``, ``clear_log()``, ``wait_requests()`` and ``wait_frames()`` are the
    segment's (``SegmentView`` comes first for that).
    """

    kind = "serial server"

    def __init__(
        self,
        slaves: Iterable[SimSlave],
        settings: LineSettings | None = None,
        *,
        host: str = "127.0.0.1",
        port: int = 0,
        log_size: int = 100_000,
    ) -> None:
        super().__init__(slaves, host=host, port=port)
        self.settings = settings or LineSettings()
        self.segment: Segment[_Client] = Segment(
            _to_client,
            lambda: self.settings,
            slaves=self.slaves,
            where=f"this {self.kind}",
            log_size=log_size,
            split_frames=True,
            on_request=self._on_request,
        )

    async def __aenter__(self) -> SimSerialServer:
        await super().__aenter__()
        return self

    def _start_tasks(self, tg: anyio.abc.TaskGroup) -> None:
        tg.start_soon(self.segment.run, name="sim serial server responder")

    def babbling(self, *, flat_out: bool = False) -> contextlib.AbstractAsyncContextManager[None]:
        """While inside, a device on the server's RS-485 port sends junk without pause at
        the port's rate (the wire never quiet for t1.5), which the server forwards to
        every client; ``flat_out``: as fast as the connections take it. Frames under way
        on the wire collide with it."""
        if flat_out:
            return self._babbling(babble_flat_out)
        tm = timing(self.settings)

        async def paced(emit: Callable[[bytes], Awaitable[None]]) -> None:
            await babble_paced(emit, tm)

        return self._babbling(paced)

    def _noted_noise(self, nbytes: int) -> None:
        self.segment.noise(nbytes, monotonic())

    def _stopped(self) -> None:
        self.segment.close()

    async def _serve(self, client: _Client) -> None:
        while data := await client.receive():
            self.segment.feed(data, monotonic(), self.settings, client)

    def _on_request(self, client: _Client, note: str) -> tuple[str, bool]:
        """Count a request; drop its connection instead if ``faults`` say so (the request
        then never goes out on the serial port: a server discards what it has not sent
        when it closes a connection)."""
        self._count_request()
        if not note and self.faults.take_drop():
            client.drop(reset=self.faults.reset)
            return "connection dropped", False
        return note, True


def _to_client(data: bytes, client: _Client) -> Awaitable[bool]:
    """Forward reply bytes to the client that asked (one that has gone just misses them)."""
    return client.send(data)
