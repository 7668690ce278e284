"""VirtualWire: a simulated RS-485 line behind a pty, with wire time and a wire log.

The master opens ``sim://NAME`` (or the pty path) with the real serial stack. The wire
reads the pty's master side and plays every attached ``SimSlave``:

* it observes the settings the master really set: baud rate and stop bits from the pty's
  termios (the kernel carries them across a pty), parity and byte size from the sim port
  class's side channel (a pty drops them) — never from the master's own bookkeeping;
* a slave only understands frames sent at its own settings; others hear garbage;
* every frame occupies the wire for its byte count times the character time, replies go
  out after the slave's turnaround, and each frame is logged with the silence before it.
"""

from __future__ import annotations

import asyncio
import os
import random
import termios
import tty
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass
from types import TracebackType

from drivebus.clock import PreciseTimer, monotonic
from drivebus.line.rtu import crc_ok, frame
from drivebus.pdu import request_length
from drivebus.settings import LineSettings
from drivebus.sim.slave import Fault, SimSlave
from drivebus.tasks import ServiceTasks
from drivebus.timing import switch_silence, timing

__all__ = ["VirtualWire", "WireFrame", "lookup_wire"]

_REGISTRY: dict[str, VirtualWire] = {}

_SPEEDS = {
    getattr(termios, name): int(name[1:])
    for name in dir(termios)
    if name[:1] == "B" and name[1:].isdigit() and int(name[1:]) >= 50
}


def lookup_wire(name: str) -> VirtualWire:
    """The running wire called ``name``; KeyError if there is none."""
    return _REGISTRY[name]


@dataclass(slots=True)
class WireFrame:
    """One frame on the simulated wire, as the wire observed it."""

    direction: str  # "request" (master to slaves) or "reply"
    address: int
    data: bytes
    start: float
    end: float
    settings: LineSettings
    gap: float  # silence before this frame
    required: float  # silence the wire rules require before it
    note: str = ""  # "", "no slave", "settings mismatch", "bad crc", "incomplete", ...

    @property
    def violation(self) -> bool:
        """True if the frame started before the required silence had passed."""
        return self.gap < self.required


class VirtualWire:
    """A simulated RS-485 line; use as ``async with VirtualWire("name") as wire``."""

    def __init__(self, name: str, *, echo: bool = False, log_size: int = 200_000) -> None:
        self.name = name
        self.echo = echo
        """Send every master byte back, as adapters that hear their own transmitter do."""
        self.slaves: dict[int, SimSlave] = {}
        self.log: deque[WireFrame] = deque(maxlen=log_size)
        self.violations = 0
        self.frames = 0
        self._master_fd = -1
        self._slave_fd = -1
        self.slave_path = ""
        self._format: tuple[int, str] | None = None  # (bytesize, parity) from the side channel
        self._busy_until = 0.0
        self._last_settings: LineSettings | None = None
        self._rx: bytearray = bytearray()
        self._rx_start = 0.0
        self._rx_end = 0.0
        self._rx_settings: LineSettings | None = None
        self._rx_gap = (0.0, 0.0)
        self._rx_collision = False
        self._pending: deque[_Reply] = deque()
        self._wake: asyncio.Future[None] | None = None
        self._timer = PreciseTimer()
        self._tg: ServiceTasks | None = None
        self._rng = random.Random(0)
        self._log_waiters: list[tuple[Callable[[], bool], asyncio.Future[None]]] = []
        self.request_count = 0
        """Master frames seen since the wire started (not reset by ``clear_log``)."""

    # -- set-up -------------------------------------------------------------------------

    def attach(self, slave: SimSlave) -> SimSlave:
        """Put ``slave`` on the wire; its address must be free."""
        if slave.address in self.slaves:
            raise ValueError(f"address {slave.address} is taken on wire {self.name!r}")
        self.slaves[slave.address] = slave
        return slave

    @property
    def url(self) -> str:
        """The URL a ``SerialLine`` opens to reach this wire."""
        return f"sim://{self.name}"

    async def __aenter__(self) -> VirtualWire:
        if self.name in _REGISTRY:
            raise ValueError(f"a virtual wire named {self.name!r} is already running")
        self._master_fd, self._slave_fd = os.openpty()
        tty.setraw(self._slave_fd)
        self.slave_path = os.ttyname(self._slave_fd)
        os.set_blocking(self._master_fd, False)
        _REGISTRY[self.name] = self
        self._tg = ServiceTasks()
        await self._tg.__aenter__()
        self._tg.start_soon(self._responder)
        asyncio.get_running_loop().add_reader(self._master_fd, self._on_readable)
        return self

    async def __aexit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> bool | None:
        try:
            asyncio.get_running_loop().remove_reader(self._master_fd)
            assert self._tg is not None
            return await self._tg.__aexit__(exc_type, exc, tb)
        finally:
            _REGISTRY.pop(self.name, None)
            self._timer.close()
            os.close(self._master_fd)
            os.close(self._slave_fd)

    # -- what the master set --------------------------------------------------------------

    def note_format(self, bytesize: int, parity: str) -> None:
        """Side channel from the sim port class: the byte size and parity it configured."""
        self._format = (int(bytesize), str(parity))

    def observed_settings(self) -> LineSettings:
        """The line settings the master's port has right now."""
        attrs = termios.tcgetattr(self._master_fd)  # the slave side's termios
        baud = _SPEEDS.get(attrs[5], 0) or 38400
        stop = 2 if attrs[2] & termios.CSTOPB else 1
        bytesize, parity = self._format or (8, "N")
        return LineSettings(baudrate=baud, bytesize=bytesize, parity=parity, stopbits=stop)

    # -- receiving from the master ----------------------------------------------------------

    def _on_readable(self) -> None:
        now = monotonic()
        try:
            data = os.read(self._master_fd, 4096)
        except (BlockingIOError, InterruptedError):
            return
        except OSError:
            return  # EIO: nobody has the pty open right now
        if not data:
            return
        if self.echo:
            os.write(self._master_fd, data)
        s = self.observed_settings()
        tm = timing(s)
        if self._rx and (now > self._rx_end + tm.t15 or s != self._rx_settings):
            self._finish_request("incomplete")
        if not self._rx:
            required = switch_silence(self._last_settings, s)
            gap = now - self._busy_until
            # A slave still due to reply (slower than the master's timeout) collides with
            # this frame: both are lost. That is the slave's fault, not a gap violation.
            self._rx_collision = bool(self._pending)
            for r in self._pending:
                r.collided = True
            self._rx_start = now
            self._rx_settings = s
            self._rx_gap = (gap, required)
        self._rx += data
        self._rx_end = self._rx_start + tm.frame_time(len(self._rx))
        self._try_complete()

    def _try_complete(self) -> None:
        rx = self._rx
        if len(rx) < 2:
            return
        slave = self.slaves.get(rx[0])
        if slave is not None and slave.powered:
            length = slave.request_length(bytes(rx[1:]))
        else:
            length = request_length(bytes(rx[1:]))
        if length is not None and len(rx) >= length + 3:
            self._finish_request("")

    def _finish_request(self, note: str) -> None:
        data = bytes(self._rx)
        self._rx.clear()
        s = self._rx_settings
        assert s is not None
        gap, required = self._rx_gap
        start, end = self._rx_start, self._rx_end
        self._busy_until = end
        self._last_settings = s
        address = data[0]
        targets: list[SimSlave]
        if address == 0:
            targets = [sl for sl in self.slaves.values() if sl.powered]
        else:
            sl = self.slaves.get(address)
            targets = [sl] if sl is not None and sl.powered else []
            if not targets and not note:
                note = "no slave"
        heard = [sl for sl in targets if _understands(sl.settings, s)]
        if targets and not heard and not note:
            note = "settings mismatch"
        if self._rx_collision and not note:
            note = "collision"
        if gap < required and not note:
            note = "gap violation"
        good_crc = crc_ok(data)
        if heard and not good_crc and not note:
            note = "bad crc"
        self._log(WireFrame("request", address, data, start, end, s, gap, required, note))
        if note and note != "bad crc":
            return  # a slave that lost sync, or heard garbage, does not answer
        for sl in heard:
            reply = sl.on_bad_crc(data) if not good_crc else sl.handle_pdu(data[1:-2], end)
            if reply is not None and address != 0:
                self._schedule(sl, reply, end)

    def _log(self, f: WireFrame) -> None:
        self.frames += 1
        if f.violation:
            self.violations += 1
        self.log.append(f)
        if f.direction == "request":
            self.request_count += 1
        if self._log_waiters:
            self._wake_waiters()

    def _wake_waiters(self) -> None:
        keep = []
        for cond, fut in self._log_waiters:
            if cond():
                if not fut.done():
                    fut.set_result(None)
            else:
                keep.append((cond, fut))
        self._log_waiters = keep

    async def _wait(self, cond: Callable[[], bool]) -> None:
        if cond():
            return
        fut = asyncio.get_running_loop().create_future()
        self._log_waiters.append((cond, fut))
        await fut

    async def wait_requests(self, n: int) -> None:
        """Return once ``n`` master frames in all have been seen (tests synchronise on it)."""
        await self._wait(lambda: self.request_count >= n)

    async def wait_frames(self, n: int) -> None:
        """Return once ``n`` frames (requests and replies) have been logged since the start
        or the last ``clear_log``."""
        await self._wait(lambda: self.frames >= n)

    # -- replying ----------------------------------------------------------------------------

    def _schedule(self, slave: SimSlave, reply_pdu: bytes, request_end: float) -> None:
        faults = slave.faults.take()
        if Fault.NO_REPLY in faults:
            return
        address = slave.address
        if Fault.WRONG_ADDRESS in faults:
            address = int(faults[Fault.WRONG_ADDRESS] or (address % 247) + 1)
        adu = frame(address, reply_pdu)
        if Fault.CRC_DAMAGE in faults:
            adu = adu[:-1] + bytes((adu[-1] ^ 0x5A,))
        if Fault.GARBAGE in faults:
            junk = faults[Fault.GARBAGE]
            junk = junk if isinstance(junk, bytes) else bytes((0xFF, 0x00, 0x55))
            adu = junk + adu
        delay = slave.turnaround + float(faults.get(Fault.SLOW_REPLY) or 0.0)  # type: ignore[arg-type]
        tm = timing(slave.settings)
        due = request_end + delay + tm.frame_time(len(adu))
        self._pending.append(_Reply(due, adu, slave))
        if self._wake is not None and not self._wake.done():
            self._wake.set_result(None)

    async def _responder(self) -> None:
        loop = asyncio.get_running_loop()
        while True:
            if not self._pending:
                self._wake = loop.create_future()
                await self._wake
                continue
            await self._timer.sleep_until(self._pending[0].due)
            self._send_reply(self._pending.popleft())

    def _send_reply(self, reply: _Reply) -> None:
        now = monotonic()
        adu, slave = reply.adu, reply.slave
        tm = timing(slave.settings)
        master = self.observed_settings()
        data = adu
        note = ""
        if reply.collided:
            note = "collision"
        elif not _understands(master, slave.settings):
            note = "master at other settings"  # its UART decodes noise, not our frame
        if note:
            data = bytes(self._rng.randrange(256) for _ in adu)
        start = now - tm.frame_time(len(adu))
        gap = start - self._busy_until
        self._busy_until = now
        self._last_settings = slave.settings
        self._log(WireFrame("reply", adu[0], adu, start, now, slave.settings, gap, 0.0, note))
        try:
            os.write(self._master_fd, data)
        except OSError:
            return  # master closed its side; a real wire just carries it to nobody

    # -- checks for tests and the benchmark ---------------------------------------------------

    def requests(self) -> list[WireFrame]:
        """Logged master frames, oldest first."""
        return [f for f in self.log if f.direction == "request"]

    def clear_log(self) -> None:
        """Forget the log and the violation count."""
        self.log.clear()
        self.violations = 0
        self.frames = 0


@dataclass(slots=True)
class _Reply:
    due: float
    adu: bytes
    slave: SimSlave
    collided: bool = False


def _understands(slave: LineSettings, heard: LineSettings) -> bool:
    return slave == heard
