"""Modbus PDUs: encoding requests, predicting frame lengths, decoding replies.

A PDU here is ``bytes`` starting with the function code. Every transport (RTU, TCP, the
simulator) uses these functions, so there is one codec for the protocol's data unit.
"""

from __future__ import annotations

import functools
import struct
from collections.abc import Callable, Sequence

from drivebus.checks import whole, words
from drivebus.errors import ArgumentError, FrameError, ModbusException

__all__ = [
    "READ_COILS",
    "READ_DISCRETE",
    "READ_HOLDING",
    "READ_INPUT",
    "WRITE_COIL",
    "WRITE_MULTIPLE",
    "WRITE_SINGLE",
    "LengthPredictor",
    "ReplyDecoder",
    "check_exception",
    "decode_bits_reply",
    "decode_read_reply",
    "decode_write_multiple_reply",
    "decode_write_single_reply",
    "read_reply_values",
    "read_request",
    "request_length",
    "response_length",
    "write_coil_request",
    "write_multiple_request",
    "write_single_request",
]

READ_COILS = 0x01
READ_DISCRETE = 0x02
READ_HOLDING = 0x03
READ_INPUT = 0x04
WRITE_COIL = 0x05
WRITE_SINGLE = 0x06
WRITE_MULTIPLE = 0x10

MAX_READ = 125
MAX_WRITE = 123
MAX_PDU = 253
"""Longest PDU: an RTU frame (address + PDU + CRC) is at most 256 bytes."""

LengthPredictor = Callable[[bytes], "int | None"]
"""Given the PDU bytes received so far, the PDU's full length, or None if more are needed."""

ReplyDecoder = Callable[[bytes, bytes, "int | None"], list[int]]
"""What a reply PDU carries, from it, its request's PDU and the slave's address (for the
errors): ``read_reply_values``."""

_HDR = struct.Struct(">BHH")


_WORDS = tuple(struct.Struct(f">{count}H") for count in range(128))
"""The codec of ``count`` big-endian 16-bit registers, by ``count``: a reply carries at
most 127 (its byte count is one byte). A tuple, not a cache: it is read per reply."""


def _span(address: object, count: int) -> int:
    """The start address, checked, for ``count`` registers that must end by 65535."""
    a = whole("register address", address, 0, 0xFFFF)
    if a + count > 0x10000:
        raise ArgumentError(f"register address: registers {a}..{a + count - 1} run past 65535")
    return a


def read_request(function: int, address: int, count: int) -> bytes:
    """FC01-FC04 request for ``count`` registers (or bits) from ``address``; a poll makes
    the same few again and again, so each is checked and packed once."""
    try:
        return _cached_read_request(function, address, count)
    except TypeError:  # an unhashable argument: the checks name it (ArgumentError)
        return _read_request(function, address, count)


def _read_request(function: int, address: int, count: int) -> bytes:
    n = whole("register count", count, 1, MAX_READ)
    return _HDR.pack(function, _span(address, n), n)


_cached_read_request = functools.lru_cache(maxsize=1024, typed=True)(_read_request)
"""``_read_request`` once per distinct request (``typed``: ``True`` is not taken for 1)."""


def write_single_request(address: int, value: int) -> bytes:
    """FC06 request writing one register."""
    a = whole("register address", address, 0, 0xFFFF)
    return _HDR.pack(WRITE_SINGLE, a, whole("register value", value, 0, 0xFFFF))


def write_coil_request(address: int, on: bool) -> bytes:
    """FC05 request switching one coil on (0xFF00) or off (0x0000)."""
    a = whole("coil address", address, 0, 0xFFFF)
    return _HDR.pack(WRITE_COIL, a, 0xFF00 if on else 0x0000)


def write_multiple_request(address: int, values: Sequence[int]) -> bytes:
    """FC16 request writing consecutive registers."""
    vs = words("register values", values, MAX_WRITE)
    count = len(vs)
    header = _HDR.pack(WRITE_MULTIPLE, _span(address, count), count) + bytes((2 * count,))
    return header + struct.pack(f">{count}H", *vs)


def response_length(pdu: bytes) -> int | None:
    """Length of a standard reply PDU, as soon as its first bytes tell it."""
    if not pdu:
        return None
    fc = pdu[0]
    if fc & 0x80:
        return 2
    if fc in (0x01, 0x02, 0x03, 0x04, 0x17):
        return 2 + pdu[1] if len(pdu) >= 2 else None
    if fc in (0x05, 0x06, 0x0F, 0x10):
        return 5
    if fc == 0x08:
        return 5
    return None


def request_length(pdu: bytes) -> int | None:
    """Length of a standard request PDU (the slave's side), as soon as it is known."""
    if not pdu:
        return None
    fc = pdu[0]
    if fc in (0x01, 0x02, 0x03, 0x04, 0x05, 0x06, 0x08):
        return 5
    if fc in (0x0F, 0x10):
        return 6 + pdu[5] if len(pdu) >= 6 else None
    if fc == 0x17:
        return 10 + pdu[9] if len(pdu) >= 10 else None
    return 1  # unknown function: the slave answers "illegal function" after the code


def request_span(request: bytes) -> tuple[int, int, int] | None:
    """(function, first address, count) a read or write request names; None for another
    function or a short request."""
    if len(request) < 5:
        return None
    fc = request[0]
    address = int.from_bytes(request[1:3], "big")
    if fc in (0x01, 0x02, 0x03, 0x04, 0x0F, 0x10):
        return fc, address, int.from_bytes(request[3:5], "big")
    if fc in (0x05, 0x06):
        return fc, address, 1
    return None


def check_exception(
    pdu: bytes, *, slave: int | None, texts: dict[int, str] | None = None,
    request: bytes = b"", names: Callable[[int, int, int], str] | None = None,
) -> None:
    """Raise ``ModbusException`` (with the vendor's text if known) for an exception reply:
    with the address range of ``request`` and the names ``names(function, address,
    count)`` gives the registers there."""
    if pdu and pdu[0] & 0x80:
        if len(pdu) < 2:
            raise FrameError(f"slave {slave}: exception reply without a code", slave=slave)
        code = pdu[1]
        span = request_span(request)
        address, count, registers = None, 1, ""
        if span is not None:
            fc, address, count = span
            registers = names(fc, address, count) if names is not None else ""
        raise ModbusException(
            code, function=pdu[0] & 0x7F, slave=slave, text=(texts or {}).get(code),
            address=address, count=count, registers=registers,
        )


def decode_read_reply(pdu: bytes, function: int, count: int, *, slave: int | None) -> list[int]:
    """Register values of an FC03/FC04 reply, checked against the request."""
    if len(pdu) != 2 + 2 * count or pdu[0] != function or pdu[1] != 2 * count:
        _bad_read_reply(pdu, function, count, slave)
    return list(_WORDS[count].unpack_from(pdu, 2))


def read_reply_values(pdu: bytes, request: bytes, slave: int | None) -> list[int]:
    """``decode_read_reply`` for the reply to ``request`` (an FC03/FC04 request of
    ``read_request``: its function and count are read from it), as ``Bus.execute``'s
    ``decode`` takes it."""
    count = request[3] << 8 | request[4]
    if len(pdu) != 2 + 2 * count or pdu[0] != request[0] or pdu[1] != 2 * count:
        _bad_read_reply(pdu, request[0], count, slave)
    return list(_WORDS[count].unpack_from(pdu, 2))


def _bad_read_reply(pdu: bytes, function: int, count: int, slave: int | None) -> None:
    """Raise the ``FrameError`` of a read reply that does not fit its request."""
    if len(pdu) < 2 or pdu[0] != function:
        raise FrameError(
            f"slave {slave}: reply function 0x{pdu[0] if pdu else 0:02X} to request "
            f"0x{function:02X}",
            slave=slave,
        )
    raise FrameError(
        f"slave {slave}: reply carries {pdu[1]} bytes, {2 * count} expected", slave=slave
    )


def decode_bits_reply(pdu: bytes, function: int, count: int, *, slave: int | None
                      ) -> list[int]:
    """Coil or discrete input states (0/1) of an FC01/FC02 reply, checked against the
    request."""
    if len(pdu) < 2 or pdu[0] != function:
        raise FrameError(
            f"slave {slave}: reply function 0x{pdu[0] if pdu else 0:02X} to request "
            f"0x{function:02X}",
            slave=slave,
        )
    n = (count + 7) // 8
    if pdu[1] != n or len(pdu) != 2 + n:
        raise FrameError(f"slave {slave}: reply carries {pdu[1]} bytes, {n} expected",
                         slave=slave)
    return [(pdu[2 + i // 8] >> (i % 8)) & 1 for i in range(count)]


def decode_write_single_reply(pdu: bytes, request: bytes, *, slave: int | None) -> None:
    """Check that an FC06 reply echoes the request."""
    if pdu != request:
        raise FrameError(f"slave {slave}: write reply does not echo the request", slave=slave)


def decode_write_multiple_reply(pdu: bytes, request: bytes, *, slave: int | None) -> None:
    """Check that an FC16 reply repeats the request's address and count."""
    if pdu != request[:5]:
        raise FrameError(
            f"slave {slave}: write-multiple reply does not match the request", slave=slave
        )
