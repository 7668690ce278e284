"""SlaveHandle: register reads and writes to one slave address through its bus."""

from __future__ import annotations

from collections.abc import Callable, Coroutine, Sequence
from typing import Any, Protocol

from drivebus import checks
from drivebus.bus.priority import Priority
from drivebus.clock import monotonic
from drivebus.errors import ArgumentError, ConfigError, ModbusException
from drivebus.pdu import (
    MAX_PDU,
    READ_COILS,
    READ_DISCRETE,
    READ_HOLDING,
    READ_INPUT,
    LengthPredictor,
    ReplyDecoder,
    check_exception,
    decode_bits_reply,
    decode_write_multiple_reply,
    decode_write_single_reply,
    read_reply_values,
    read_request,
    response_length,
    write_coil_request,
    write_multiple_request,
    write_single_request,
)
from drivebus.settings import LineSettings

__all__ = ["Executor", "SlaveHandle", "check_line_settings", "handle_on"]


class Executor(Protocol):
    """What a slave handle needs from its bus: run one transaction for it."""

    async def execute(
        self,
        handle: SlaveHandle,
        pdu: bytes,
        *,
        expect: LengthPredictor | None,
        priority: Priority,
        idempotent: bool,
        decode: ReplyDecoder | None = None,
    ) -> Any:
        """Queue one transaction and return its reply PDU (empty for a broadcast), or what
        ``decode`` makes of it (``decode(reply, pdu, handle.address)``: a register read's
        values, decoded in the caller's coroutine, so that it needs no coroutine of its
        own)."""
        ...


class _LineSettings(Protocol):
    name: str
    settings: LineSettings | None
    per_slave_settings: bool


def check_line_settings(handle: SlaveHandle, line: _LineSettings) -> None:
    """``ConfigError`` if ``handle``'s own settings cannot be used on ``line`` (not a
    serial line, or one whose port has one setting for all slaves)."""
    if handle.settings is not None and handle.settings != line.settings:
        if line.settings is None:
            raise ConfigError(f"line {line.name} is not a serial line: no per-slave settings")
        if not line.per_slave_settings:
            raise ConfigError(
                f"slave {handle.address}: line {line.name} has one setting for all slaves "
                f"({line.settings}); {handle.settings} cannot be used on it"
            )


def handle_on(
    bus: Executor, line: _LineSettings, address: int, *, settings: LineSettings | None,
    timeout: float, retries: int, exception_texts: dict[int, str] | None, guard: float,
    frame_timeout: float,
) -> SlaveHandle:
    """A handle for the slave at ``address`` on ``bus`` (a ``Bus`` or a worker's
    ``RemoteBus``): its arguments checked, up to the highest unit id ``line`` takes, and
    its own settings checked against ``line``."""
    h = SlaveHandle(bus, address, settings=settings, timeout=timeout, retries=retries,
                    exception_texts=exception_texts, guard=guard,
                    frame_timeout=frame_timeout,
                    max_address=max(getattr(line, "unit_ids", range(248))))
    check_line_settings(h, line)
    return h


def _priority(priority: object) -> Priority:
    return checks.member("priority", priority, Priority)


class SlaveHandle:
    """One slave on a bus: its address, line settings, timeout, retries, guard interval,
    frame timeout and exception texts."""

    def __init__(
        self,
        bus: Executor,
        address: int,
        *,
        settings: LineSettings | None,
        timeout: float,
        retries: int,
        exception_texts: dict[int, str] | None = None,
        guard: float = 0.0,
        frame_timeout: float = 0.0,
        max_address: int = 247,
    ) -> None:
        what = "slave address (0 = broadcast)" if max_address == 247 else \
            "Modbus TCP unit id"
        self.address = checks.whole(what, address, 0, max_address, error=ConfigError)
        if settings is not None and not isinstance(settings, LineSettings):
            raise ConfigError(
                f"slave {address}: settings must be LineSettings (e.g. "
                f"LineSettings.parse('9600 8N1')) or None, not {settings!r}"
            )
        self.bus = bus
        self.settings = settings
        self.timeout = checks.response_timeout(f"slave {address}: response timeout", timeout)
        self.retries = checks.retry_count(f"slave {address}: retries", retries)
        self.exception_texts = dict(exception_texts or {})
        self.register_names: Callable[[int, int, int], str] | None = None
        """What the registers a request names are called (function, first address,
        count): set by the drive's profile, said in its Modbus exceptions."""
        self.guard = checks.guard_interval(f"slave {address}: guard", guard)
        """Extra quiet time (s) the line keeps before each of this slave's frames, on top
        of its silence (a slow drive's guard interval); 0: none."""
        self.frame_timeout = checks.guard_interval(f"slave {address}: frame timeout",
                                                   frame_timeout)
        self.wrote_at = 0.0
        """When the reply to the last write to this slave came in (monotonic s): a status
        whose request left before then cannot tell what that write did."""
        """Extra quiet time (s) after each of its replies, for bytes the drive trails after
        its frame, before the line's next frame (to any slave); 0: none."""

    @property
    def is_broadcast(self) -> bool:
        """True for address 0: writes reach every slave and nobody answers."""
        return self.address == 0

    def raise_exception(self, reply: bytes, request: bytes = b"") -> None:
        """Raise the typed error for an exception reply, with the vendor's text, the
        address range of ``request`` and the names of the registers there."""
        check_exception(reply, slave=self.address, texts=self.exception_texts,
                        request=request, names=self.register_names)
        raise ModbusException(0, function=reply[0] & 0x7F, slave=self.address)  # unreachable

    def _no_broadcast_read(self) -> None:
        if self.is_broadcast:
            raise ConfigError("cannot read from the broadcast address 0: nobody answers")

    def _read(self, function: int, address: int, count: int, priority: Priority
              ) -> Coroutine[Any, Any, list[int]]:
        """The bus's ``execute`` coroutine for a register read (one coroutine per read:
        ``execute`` decodes the reply); a refused read raises when it is awaited."""
        try:
            if self.address == 0:
                self._no_broadcast_read()
            req = read_request(function, address, count)
            if type(priority) is not Priority:
                priority = _priority(priority)
        except Exception as exc:  # (raised where the read is awaited, as by a coroutine)
            return _refused(exc)
        return self.bus.execute(  # type: ignore[no-any-return]
            self, req, expect=response_length, priority=priority, idempotent=True,
            decode=read_reply_values)

    async def _write(
        self,
        req: bytes,
        check: Callable[..., None],
        priority: Priority,
        idempotent: bool,
    ) -> None:
        reply = await self.bus.execute(
            self,
            req,
            expect=None if self.is_broadcast else response_length,
            priority=_priority(priority),
            idempotent=bool(idempotent),
        )
        self.wrote_at = monotonic()
        if not self.is_broadcast:
            check(reply, req, slave=self.address)

    # The two register reads are coroutine functions that return the bus's ``execute``
    # coroutine (awaiting it here would put one more frame in every step of a poll's task).

    def read_holding_registers(
        self, address: int, count: int, *, priority: Priority = Priority.CONFIG
    ) -> Coroutine[Any, Any, list[int]]:
        """Read ``count`` holding registers (FC03); retried on timeout or bad frame."""
        return self._read(READ_HOLDING, address, count, priority)

    def read_input_registers(
        self, address: int, count: int, *, priority: Priority = Priority.CONFIG
    ) -> Coroutine[Any, Any, list[int]]:
        """Read ``count`` input registers (FC04); retried on timeout or bad frame."""
        return self._read(READ_INPUT, address, count, priority)

    async def read_coils(
        self, address: int, count: int, *, priority: Priority = Priority.CONFIG
    ) -> list[int]:
        """Read ``count`` coils (FC01) as 0/1; retried on timeout or bad frame."""
        return await self._read_bits(READ_COILS, address, count, priority)

    async def read_discrete_inputs(
        self, address: int, count: int, *, priority: Priority = Priority.CONFIG
    ) -> list[int]:
        """Read ``count`` discrete inputs (FC02) as 0/1; retried on timeout or bad frame."""
        return await self._read_bits(READ_DISCRETE, address, count, priority)

    async def _read_bits(self, function: int, address: int, count: int, priority: Priority
                         ) -> list[int]:
        self._no_broadcast_read()
        req = read_request(function, address, count)
        reply = await self.bus.execute(
            self, req, expect=response_length, priority=_priority(priority), idempotent=True
        )
        return decode_bits_reply(reply, function, int(count), slave=self.address)

    async def write_coil(
        self,
        address: int,
        on: bool,
        *,
        priority: Priority = Priority.CONFIG,
        idempotent: bool = True,
    ) -> None:
        """Switch one coil (FC05). Mark commands ``idempotent=False``: never retried."""
        req = write_coil_request(address, bool(on))
        await self._write(req, decode_write_single_reply, priority, idempotent)

    async def write_register(
        self,
        address: int,
        value: int,
        *,
        priority: Priority = Priority.CONFIG,
        idempotent: bool = True,
    ) -> None:
        """Write one register (FC06). Mark commands ``idempotent=False``: never retried."""
        req = write_single_request(address, value)
        await self._write(req, decode_write_single_reply, priority, idempotent)

    async def write_registers(
        self,
        address: int,
        values: Sequence[int],
        *,
        priority: Priority = Priority.CONFIG,
        idempotent: bool = True,
    ) -> None:
        """Write consecutive registers (FC16). Mark commands ``idempotent=False``."""
        req = write_multiple_request(address, values)
        await self._write(req, decode_write_multiple_reply, priority, idempotent)

    async def transact(
        self,
        pdu: bytes,
        *,
        expect: LengthPredictor | None = response_length,
        priority: Priority = Priority.CONFIG,
        idempotent: bool = False,
    ) -> bytes:
        """Raw path: send any PDU and return the reply PDU, its length told by ``expect``.

        For drives with non-standard frames; exception replies still raise.
        """
        if not isinstance(pdu, bytes | bytearray | memoryview) or not 1 <= len(pdu) <= MAX_PDU:
            raise ArgumentError(
                f"pdu: expected 1..{MAX_PDU} bytes (function code first), got {pdu!r}"
            )
        if expect is not None and not callable(expect):
            raise ArgumentError(
                f"expect: expected a reply-length function or None, got {expect!r}"
            )
        return await self.bus.execute(
            self, bytes(pdu), expect=expect, priority=_priority(priority),
            idempotent=bool(idempotent),
        )

    def __repr__(self) -> str:
        return f"SlaveHandle({self.address}, settings={self.settings})"


async def _refused(exc: BaseException) -> list[int]:
    """A read refused before it was queued: raises ``exc`` when awaited."""
    raise exc
