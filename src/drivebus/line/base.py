"""What every line (serial RTU, Modbus TCP, RTU over TCP) offers the bus scheduler.

A line declares what it can do (``per_slave_settings``, ``local_echo``, ``max_in_flight``,
``counts_garbage``) as typed attributes, so the scheduler and tools read them instead of
probing the object.
"""

from __future__ import annotations

import abc
import asyncio
from collections.abc import Callable
from dataclasses import dataclass
from types import TracebackType
from typing import Protocol

from drivebus.pdu import LengthPredictor
from drivebus.settings import LineSettings

__all__ = ["Begun", "Exchange", "Line", "SendWithdrawn"]


class SendWithdrawn(Exception):
    """A request taken back before its frame went out (``Line.withdraw``, or bytes during
    its silence on a ``withdrawable`` transaction): nothing was sent; plan again."""


class Begun(Protocol):
    """A transaction started with ``Line.begin``: its ``future`` is done once it needs
    its owner no more (a sound reply, told to ``on_reply``) or needs ``Line.finish``.
    A sound reply that ``on_reply`` takes over (it returns True) may leave it undone."""

    on_done: Callable[[asyncio.Future[None]], None] | None
    """A done callback of its future (set before the future is first used)."""

    @property
    def future(self) -> asyncio.Future[None]:
        """Done when the transaction needs its owner no more, or needs ``finish``."""
        ...

    def done(self) -> bool:
        """Whether ``future`` is done (without making one that is not needed yet)."""
        ...


@dataclass(slots=True)
class Exchange:
    """One completed transaction as the line saw it: the reply and its wire times."""

    reply: bytes
    """Reply PDU (function code onwards); empty for a broadcast."""
    tx_start: float
    tx_end: float
    rx_end: float
    request_bytes: int
    reply_bytes: int
    wire_time: float
    """Time the frames of this exchange occupied the wire (request + reply bytes)."""


class Line(abc.ABC):
    """A medium that carries Modbus transactions, one at a time unless it says otherwise."""

    name: str
    """What error messages call the line (a port, ``tcp://host:port``, ...)."""

    settings: LineSettings | None
    """Default line settings (None for plain Modbus TCP, which has none)."""

    # -- capabilities: class defaults, set per class or per instance by each line ------------

    unit_ids: range = range(0, 248)
    """The slave addresses a request may carry: 0 (broadcast) and 1..247 on RS-485 and
    RTU over TCP, a Modbus TCP unit identifier 0..255 (many devices want 255, "FFh")."""

    per_slave_settings: bool = False
    """Each slave may have its own baud rate and format: the line reconfigures its port
    before a frame at other settings (and keeps the longer silence)."""

    local_echo: bool = False
    """The medium hears its own transmitter: every frame sent comes back first and is
    consumed before the reply."""

    max_in_flight: int = 1
    """How many requests the line can have outstanding at once (replies matched by id)."""

    counts_garbage: bool = False
    """``garbage_bytes`` counts the bytes received outside any reply; False: always 0."""

    waits_for_silence: bool = False
    """``transact`` waits for the line's silence itself, sends the frame right at its end,
    tells ``on_reply`` of a complete exchange and accepts ``withdrawable=True``: until the
    frame is out the request can be taken back (``withdraw()``), and bytes arriving during
    the silence end it (``SendWithdrawn`` both). A bus hands such a line its next request
    at once instead of sleeping first."""

    begins: bool = False
    """The line also offers ``transact`` in two halves: ``begin`` (the same arguments,
    ``withdrawable`` and ``on_reply`` included) starts it from the caller and returns at
    once, the frame going out from the silence timer's callback; its ``future`` is done
    when the transaction needs its owner no more (``on_reply`` has had a sound exchange)
    or needs ``finish(begun)``, awaited, to judge what came (and raise what failed). A
    scheduler can thus run the line from callbacks while every transaction goes well."""

    foreign_report: Callable[[bytes], None] | None = None
    """Called with each request frame of another master the line hears among the bytes
    nobody asked for (lines that hear the bus: serial RTU and RTU over TCP); the bus that
    owns the line sets it (``drivebus.line.foreign``)."""

    def _heard_foreign(self, request: bytes) -> None:
        """The receiver's report of another master's request: pass it on."""
        report = self.foreign_report
        if report is not None:
            report(request)

    def withdraw(self) -> bool:
        """Take back the ``withdrawable`` transaction waiting for its silence, if its frame
        has not gone out (it raises ``SendWithdrawn``); False if there is none."""
        return False

    @property
    def garbage_bytes(self) -> int:
        """Bytes received outside any reply (late answers, noise), discarded."""
        return 0

    # -- life cycle and transactions ---------------------------------------------------------

    @abc.abstractmethod
    async def open(self) -> None:
        """Open the port or connection; raise ``LineClosed`` naming the cause if it cannot."""

    @abc.abstractmethod
    async def close(self) -> None:
        """Close; a transaction waiting on the line fails with ``LineClosed``."""

    def last_activity(self) -> float:
        """Monotonic time the line's last known traffic ended (a frame sent, a byte
        received; 0: the line keeps no silences). While the line is idle it moves only
        when bytes arrive that nobody asked for: the scheduler reads that as noise."""
        return 0.0

    def ready_at(self, settings: LineSettings | None) -> float:
        """Monotonic time from which a frame at ``settings`` may start (0: at once)."""
        return 0.0

    @abc.abstractmethod
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
        """Send ``pdu`` to ``unit`` and return its reply (``expect=None``: no reply).

        ``timeout`` bounds the wait for the reply once the request is out. A line that
        keeps silences bounds the wait before it too: if received bytes keep it busy
        until ``quiet_by`` (default: ``timeout`` from now), ``LineNoise`` with
        ``sent=False``. A reply drowned in noise is ``LineNoise`` with ``sent=True``.
        Lines that declare ``waits_for_silence`` also take ``withdrawable`` and
        ``on_reply`` (keywords): ``on_reply(exchange)`` is called once the exchange is
        complete, before ``transact`` returns it (from the callback that received the
        reply's last byte, where it can), so a scheduler can wake the caller from there.
        """

    async def __aenter__(self) -> Line:
        await self.open()
        return self

    async def __aexit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        await self.close()
