"""What every line (serial RTU, Modbus TCP, RTU over TCP) offers the bus scheduler."""

from __future__ import annotations

import abc
from dataclasses import dataclass
from types import TracebackType

from drivebus.pdu import LengthPredictor
from drivebus.settings import LineSettings

__all__ = ["Exchange", "Line"]


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
    """A medium that carries one Modbus transaction at a time."""

    settings: LineSettings | None
    """Default line settings (None for plain Modbus TCP)."""

    name: str

    @abc.abstractmethod
    async def open(self) -> None:
        """Open the port or connection; raise ``LineClosed`` naming the cause if it cannot."""

    @abc.abstractmethod
    async def close(self) -> None:
        """Close; a transaction waiting on the line fails with ``LineClosed``."""

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
    ) -> Exchange:
        """Send ``pdu`` to ``unit`` and return its reply (``expect=None``: no reply)."""

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
