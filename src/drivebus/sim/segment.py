"""Segment: the simulated RS-485 segment, whatever carries the master's bytes to it.

A segment plays every attached ``SimSlave``. A front-end feeds it the master's bytes with
their arrival time and the settings they were sent at (``feed``); the segment

* assembles request frames, gives each its wire time (its byte count times the character
  time) and the silence before it, and logs it with what went wrong: "no slave",
  "settings mismatch", "collision", "gap violation", "bad crc", "incomplete", and for a
  pty's read that held two whole frames (the silence between them hidden: a retry read
  late on a starved machine) "unanswered: the next request came with it" on the first;
* lets the slaves that understood the frame act (a slave only understands frames sent at
  its own settings; address 0 reaches every powered slave and nobody answers);
* schedules their replies, with the slaves' ``FaultPlan`` faults applied, for the end of
  the turnaround plus the reply's wire time; ``run`` hands each reply to the front-end's
  ``deliver`` callback at that time, with the route the request came by. It judges the
  reply (the master's settings, a collision) a little before, so that its own
  bookkeeping does not make the reply late, and logs it after the bytes have left.

Front-ends: ``VirtualWire`` (a pty; settings observed from termios and a side channel)
and ``SimSerialServer`` (RTU over TCP; the port's fixed settings, replies per client).
"""

from __future__ import annotations

import math
import random
from collections import deque
from collections.abc import Awaitable, Callable
from dataclasses import dataclass
from typing import Any, Generic, TypeVar

import anyio

from drivebus.clock import PreciseTimer, monotonic, spin_until
from drivebus.line.rtu import crc_ok, frame
from drivebus.pdu import request_length
from drivebus.settings import LineSettings
from drivebus.sim.slave import Fault, SimSlave
from drivebus.timing import switch_silence, timing

__all__ = ["Segment", "SegmentView", "WireFrame", "add_slave"]

R = TypeVar("R")
"""How a front-end routes a reply back to the master that asked (a connection, or None)."""

_GARBAGE = bytes((0xFF, 0x00, 0x55))
_UNANSWERED = "unanswered: the next request came with it"
_PREPARE = 40e-6
"""How long before a reply is due ``run`` wakes to judge it (reading the master's settings
takes some 20-30 us in a busy simulator process); the rest of the time is spun."""
_ROUNDING = 1e-9
"""A silence short of the required one by less than this (1 ns) is the float rounding of
times near the monotonic clock's magnitude (a start computed as an end plus a silence),
not a violation: one that fell either way with the hour of the clock was flaky."""


def _too_short(gap: float, required: float) -> bool:
    """Whether a silence of ``gap`` s broke a rule that requires ``required`` s."""
    return gap < required - _ROUNDING


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
        return _too_short(self.gap, self.required)


def add_slave(slaves: dict[int, SimSlave], slave: SimSlave, where: str) -> SimSlave:
    """Put ``slave`` in ``slaves`` at its address, which must be free on ``where``."""
    if slave.address in slaves:
        raise ValueError(f"address {slave.address} is taken on {where}")
    slaves[slave.address] = slave
    return slave


class _Incoming(Generic[R]):
    """A request frame being received: its bytes so far and their place on the wire."""

    def __init__(
        self,
        start: float,
        settings: LineSettings,
        route: R,
        *,
        quiet_since: float,
        previous: LineSettings | None,
        collided: bool,
    ) -> None:
        self.start = start
        self.end = start
        self.settings = settings
        self.route = route
        self.gap = start - quiet_since
        """The silence before the frame."""
        self.required = switch_silence(previous, settings)
        """The silence the wire rules require after traffic at ``previous`` settings."""
        self.collided = collided
        """A reply was still due: both are lost."""
        self.data = bytearray()

    def add(self, data: bytes) -> None:
        """Append ``data``; the frame now ends after all its bytes' wire time."""
        self.data += data
        self.end = self.start + timing(self.settings).frame_time(len(self.data))

    def cut(self, n: int) -> bytes:
        """Keep the first ``n`` bytes as this frame; give back the rest."""
        rest = bytes(self.data[n:])
        del self.data[n:]
        self.end = self.start + timing(self.settings).frame_time(n)
        return rest


@dataclass(eq=False)
class _Reply(Generic[R]):
    """A slave's reply due on the wire."""

    due: float
    adu: bytes
    slave: SimSlave
    route: R
    collided: bool = False


class Segment(Generic[R]):
    """One simulated RS-485 segment with its slaves, wire log and pending replies.

    ``deliver(data, route)`` hands reply bytes to the master at once (``route`` is what
    ``feed`` got with the request), or returns an awaitable that finishes the handing
    over (a stream, an adapter that holds the bytes); ``master_settings()`` says what the
    master's port is set to when a reply arrives (a master at other settings decodes
    noise). ``split_frames``: the master's bytes reach the wire through a transmit
    buffer, as in a serial server, so frames that arrive in one chunk go out back to back
    and a frame starts no earlier than the previous one ended; without it, what arrives
    is on the wire at once, and the bytes received when a frame is complete are that
    frame. ``on_request(route, note)`` lets the front-end judge each finished request
    before it goes out: it returns the note to go on with and whether the frame goes out
    on the wire at all (False: the front-end discarded it first, as a serial server that
    closes the connection instead of sending it; the frame is logged with that note, and
    the wire stays as quiet as it was).
    """

    def __init__(
        self,
        deliver: Callable[[bytes, R], Awaitable[object] | None],
        master_settings: Callable[[], LineSettings],
        *,
        slaves: dict[int, SimSlave] | None = None,
        where: str = "this segment",
        log_size: int = 200_000,
        split_frames: bool = False,
        on_request: Callable[[R, str], tuple[str, bool]] | None = None,
        strict: bool = True,
    ) -> None:
        self.slaves: dict[int, SimSlave] = {} if slaves is None else slaves
        """The slaves on the segment by address (the front-end's own table, if it gave one)."""
        self.where = where
        self.split_frames = split_frames
        self.strict = strict
        """Slaves lose a frame sent without the required silence (the spec); False: they
        answer it anyway (lenient real-world slaves) and the violation is only logged."""
        self.log: deque[WireFrame] = deque(maxlen=log_size)
        self.violations = 0
        self.frames = 0
        self.request_count = 0
        """Master frames seen since the segment started (not reset by ``clear_log``)."""
        self.noise_bytes = 0
        """Bytes of noise (from no master and no slave) put on the wire so far."""
        self._deliver = deliver
        self._master_settings = master_settings
        self._on_request = on_request
        self._rx: _Incoming[R] | None = None
        self._request_end = 0.0  # when the last request frame left the wire
        self._busy_until = -math.inf  # when the last frame of either direction did (none
        # yet: the first frame's gap is infinite)
        self._last_settings: LineSettings | None = None
        self._pending: deque[_Reply[R]] = deque()
        self._wake: anyio.Event | None = None
        self._changed: anyio.Event | None = None
        self._timer = PreciseTimer()
        self._rng = random.Random(0)

    def attach(self, slave: SimSlave) -> SimSlave:
        """Put ``slave`` on the segment; its address must be free."""
        return add_slave(self.slaves, slave, self.where)

    def slave_at(self, address: int) -> SimSlave | None:
        """The slave that answers at ``address`` now (a drive that took a new address at
        power-up answers at that one, not at the one it was attached with)."""
        sl = self.slaves.get(address)
        if sl is not None and sl.address == address:
            return sl
        return next((x for x in self.slaves.values() if x.address == address), None)

    # -- the master's bytes -----------------------------------------------------------------

    def feed(self, data: bytes, now: float, settings: LineSettings, route: R) -> None:
        """Take bytes that reached the segment at ``now``, sent at ``settings`` by the master
        reached through ``route``."""
        rx = self._rx
        if rx is not None and (
            now > rx.end + timing(settings).t15 or settings != rx.settings or route is not rx.route
        ):
            self._finish("incomplete")
        if self._rx is None:
            start = max(now, self._request_end) if self.split_frames else now
            self._rx = self._begin(start, settings, route)
        self._rx.add(data)
        while (rx := self._rx) is not None and (n := self._complete_length(rx.data)) is not None:
            rest = rx.cut(n) if n < len(rx.data) else b""
            if rest and not self.split_frames:
                # Two whole frames in one read: the pty hid the silence between them (a
                # master's retry after a timeout, read late on a starved machine). The
                # first goes unanswered: its master has moved on to the next.
                self._finish("", answered=False)
                start = self._request_end + switch_silence(settings, settings)
            else:
                self._finish("")
                start = self._request_end  # from a transmit buffer: no silence at all
            if rest:
                self._rx = self._begin(start, settings, route)
                self._rx.add(rest)

    def _begin(self, start: float, settings: LineSettings, route: R) -> _Incoming[R]:
        # A slave still due to reply (slower than the master's timeout) collides with this
        # frame: both are lost. That is the slave's fault, not a gap violation.
        for r in self._pending:
            r.collided = True
        return _Incoming(
            start,
            settings,
            route,
            quiet_since=self._busy_until,
            previous=self._last_settings,
            collided=bool(self._pending),
        )

    def _complete_length(self, rx: bytearray) -> int | None:
        """How many bytes of ``rx`` make the request, once all of it is there (None: not
        yet). With ``split_frames``, that frame's length; without, all the bytes, unless
        they are two whole frames with good CRCs (then the first's length; a frame with a
        good CRC and the start of another: not yet)."""
        length = self._frame_length(rx)
        if length is None or len(rx) < length:
            return None
        if self.split_frames or len(rx) == length:
            return length
        if not crc_ok(bytes(rx[:length])):
            return len(rx)
        rest = rx[length:]
        follows = self._frame_length(rest)
        if follows is None or len(rest) < follows:
            # A whole frame, and the start of another: the kernel handed one write of two
            # frames over in pieces (its buffer ended inside the second). Wait for the rest.
            return None
        return length if crc_ok(bytes(rest[:follows])) else len(rx)

    def _frame_length(self, rx: bytearray) -> int | None:
        """The length of the request frame that ``rx`` begins with (address to CRC), as
        the slave it is for reads it; None while too little of it is there to say."""
        if len(rx) < 2:
            return None
        slave = self.slave_at(rx[0])
        if slave is not None and slave.powered:
            length = slave.request_length(bytes(rx[1:]))
        else:
            length = request_length(bytes(rx[1:]))
        return None if length is None else length + 3

    def _finish(self, note: str, *, answered: bool = True) -> None:
        rx, self._rx = self._rx, None
        assert rx is not None
        data = bytes(rx.data)
        if self._on_request is not None:
            note, on_wire = self._on_request(rx.route, note)
            if not on_wire:
                self._log(WireFrame("request", data[0], data, rx.start, rx.end, rx.settings,
                                    rx.gap, rx.required, note))
                return
        self._request_end = rx.end
        self._busy_until = max(self._busy_until, rx.end)
        self._last_settings = rx.settings
        heard, note = self._hearers(data, rx, note)
        lenient = note == "gap violation" and not self.strict
        if not answered and not note:
            note = _UNANSWERED
        self._log(WireFrame("request", data[0], data, rx.start, rx.end, rx.settings, rx.gap,
                            rx.required, note))
        if not answered:
            if note == _UNANSWERED or lenient:
                for sl in heard:  # the slave acts on it; its master no longer listens
                    sl.handle_pdu(data[1:-2], rx.end)
            return
        if note and note != "bad crc" and not lenient:
            return  # a slave that lost sync, or heard garbage, does not answer
        if lenient:
            note = ""
        good_crc = note != "bad crc" and crc_ok(data)
        for sl in heard:
            reply = sl.handle_pdu(data[1:-2], rx.end) if good_crc else sl.on_bad_crc(data)
            if reply is not None and data[0] != 0:
                self._schedule(sl, reply, rx.end, rx.route)

    def _hearers(self, data: bytes, rx: _Incoming[R], note: str) -> tuple[list[SimSlave], str]:
        """The slaves that decode the request, and the note it gets (the first that applies)."""
        address = data[0]
        if address == 0:
            targets = [sl for sl in self.slaves.values() if sl.powered]
        else:
            sl = self.slave_at(address)
            targets = [sl] if sl is not None and sl.powered else []
            if not targets and not note:
                note = "no slave"
        heard = [sl for sl in targets if sl.settings == rx.settings]
        if targets and not heard and not note:
            note = "settings mismatch"
        if rx.collided and not note:
            note = "collision"
        if _too_short(rx.gap, rx.required) and not note:
            note = "gap violation"
        if heard and not note and not crc_ok(data):
            note = "bad crc"
        return heard, note

    # -- noise ------------------------------------------------------------------------------

    def noise(self, nbytes: int, now: float) -> None:
        """``nbytes`` of noise (a babbling device, interference) were on the wire until
        ``now``: a request or reply under way is corrupted (both collide), and the next
        frame needs its full silence after the noise."""
        self.noise_bytes += nbytes
        self._busy_until = max(self._busy_until, now)
        if self._rx is not None:
            self._rx.collided = True
        for r in self._pending:
            r.collided = True

    # -- the slaves' replies ------------------------------------------------------------------

    def _schedule(self, slave: SimSlave, reply_pdu: bytes, request_end: float, route: R) -> None:
        faults = slave.faults.take()
        if Fault.NO_REPLY in faults:
            return
        adu = _faulty_frame(slave.address, reply_pdu, faults)
        delay = slave.turnaround + float(faults.get(Fault.SLOW_REPLY) or 0.0)  # type: ignore[arg-type]
        due = request_end + delay + timing(slave.settings).frame_time(len(adu))
        self._pending.append(_Reply(due, adu, slave, route))
        if self._wake is not None:
            self._wake.set()

    async def run(self) -> None:
        """Put each reply on the wire and deliver it at its due time, for ever (the
        front-end runs this as a service task)."""
        while True:
            if not self._pending:
                self._wake = anyio.Event()
                await self._wake.wait()
                continue
            await self._timer.sleep_until(self._pending[0].due - _PREPARE)
            await self._send(self._pending.popleft())

    async def _send(self, reply: _Reply[R]) -> None:
        adu, settings = reply.adu, reply.slave.settings
        # Judged just before its time (``_PREPARE``): a master that changes its settings
        # in the last tens of microseconds of a reply is not a case a UART resolves either.
        other_settings = self._master_settings() != settings
        spin_until(reply.due)
        note = ""
        if reply.collided:
            note = "collision"
        elif other_settings:
            note = "master at other settings"  # its UART decodes noise, not our frame
        data = bytes(self._rng.randrange(256) for _ in adu) if note else adu
        # The reply's last byte is on the wire when it is handed over: stamp it then, and
        # log it after the bytes have left, so that the log shows the wire, not the sim.
        now = monotonic()
        rest = self._deliver(data, reply.route)
        start = now - timing(settings).frame_time(len(adu))
        gap = start - self._busy_until
        self._busy_until = max(self._busy_until, now)
        self._last_settings = settings
        self._log(WireFrame("reply", adu[0], adu, start, now, settings, gap, 0.0, note))
        if rest is not None:
            await rest

    def close(self) -> None:
        """Release the reply timer (once ``run`` has ended)."""
        self._timer.close()

    # -- the wire log -------------------------------------------------------------------------

    def _log(self, f: WireFrame) -> None:
        self.frames += 1
        if f.violation:
            self.violations += 1
        self.log.append(f)
        if f.direction == "request":
            self.request_count += 1
        if self._changed is not None:
            self._changed.set()
            self._changed = None

    async def _wait(self, cond: Callable[[], bool]) -> None:
        while not cond():
            if self._changed is None:
                self._changed = anyio.Event()
            await self._changed.wait()

    async def wait_requests(self, n: int) -> None:
        """Return once ``n`` master frames in all have been seen."""
        await self._wait(lambda: self.request_count >= n)

    async def wait_frames(self, n: int) -> None:
        """Return once ``n`` frames have been logged since the start or the last ``clear_log``."""
        await self._wait(lambda: self.frames >= n)

    def requests(self) -> list[WireFrame]:
        """Logged master frames, oldest first."""
        return [f for f in self.log if f.direction == "request"]

    def clear_log(self) -> None:
        """Forget the log and the violation count."""
        self.log.clear()
        self.violations = 0
        self.frames = 0


def _faulty_frame(address: int, pdu: bytes, faults: dict[Fault, Any]) -> bytes:
    """The RTU frame of a reply with the slave's WRONG_ADDRESS, CRC_DAMAGE and GARBAGE
    faults applied."""
    if Fault.WRONG_ADDRESS in faults:
        address = int(faults[Fault.WRONG_ADDRESS] or (address % 247) + 1)
    adu = frame(address, pdu)
    if Fault.CRC_DAMAGE in faults:
        adu = adu[:-1] + bytes((adu[-1] ^ 0x5A,))
    if Fault.GARBAGE in faults:
        junk = faults[Fault.GARBAGE]
        adu = (junk if isinstance(junk, bytes) else _GARBAGE) + adu
    return adu


class SegmentView:
    """The wire log of a front-end's ``segment``, shown on the front-end itself."""

    segment: Segment[Any]

    @property
    def log(self) -> deque[WireFrame]:
        """Every frame on the wire, oldest first (bounded)."""
        return self.segment.log

    @property
    def violations(self) -> int:
        """Logged frames that came before the required silence had passed."""
        return self.segment.violations

    @property
    def frames(self) -> int:
        """Frames logged since the start or the last ``clear_log``."""
        return self.segment.frames

    @property
    def request_count(self) -> int:
        """Master frames seen since the start (not reset by ``clear_log``)."""
        return self.segment.request_count

    @property
    def noise_bytes(self) -> int:
        """Bytes of noise put on the wire so far (``babbling()``)."""
        return self.segment.noise_bytes

    def requests(self) -> list[WireFrame]:
        """Logged master frames, oldest first."""
        return self.segment.requests()

    def clear_log(self) -> None:
        """Forget the log and the violation count."""
        self.segment.clear_log()

    async def wait_requests(self, n: int) -> None:
        """Return once ``n`` master frames in all have been seen (tests synchronise on it)."""
        await self.segment.wait_requests(n)

    async def wait_frames(self, n: int) -> None:
        """Return once ``n`` frames (requests and replies) have been logged since the start
        or the last ``clear_log``."""
        await self.segment.wait_frames(n)
