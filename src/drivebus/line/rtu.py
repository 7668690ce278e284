"""RTU framing: CRC-16 and application data units (address + PDU + CRC).

The CRC is the one of "MODBUS over Serial Line" v1.02 (section 6.2.2 and its appendix B):
CRC-16 with polynomial 0xA001 (0x8005 reflected), initial value 0xFFFF, sent low byte
first. It is computed from tables: the spec's 256-entry one (one lookup per byte), and
one of the register after two bytes (one lookup per two bytes: a third of the Python work
per byte). Built frames are cached: a poll sends the same few frames again
and again, so each one's CRC is computed once.
"""

from __future__ import annotations

import struct
from array import array

__all__ = ["crc16", "crc16_value", "crc_ok", "frame"]

_POLY = 0xA001


def _table() -> tuple[int, ...]:
    table = []
    for byte in range(256):
        crc = byte
        for _ in range(8):
            crc = (crc >> 1) ^ _POLY if crc & 1 else crc >> 1
        table.append(crc)
    return tuple(table)


_TABLE = _table()
"""The CRC of each byte value, shifted through the register once."""

_FRAMES: dict[tuple[int, bytes], bytes] = {}
"""Frames built so far, by address and PDU."""
_FRAMES_MAX = 4096


def _pair_table() -> array:
    """The register after two bytes, by register XOR the two bytes (low byte first): two
    table steps depend only on that, so a frame is checked two bytes per lookup."""
    t = _TABLE
    out = array("H")
    for hi in range(256):  # entry hi << 8 | lo: the first step's byte lo, the second's hi
        out.extend([(t[lo] >> 8) ^ t[(hi ^ t[lo]) & 0xFF] for lo in range(256)])
    return out


_PAIRS = _pair_table()
"""``_pair_table()`` (128 KiB), made when the module is imported: some milliseconds that
must not fall in a step of an event loop."""
_UNPACK = tuple(struct.Struct(f"<{k}H").unpack_from for k in range(129))
"""The little-endian 16-bit words of the first 2k bytes, by k (a frame has at most 256)."""


def crc16_value(data: bytes | bytearray | memoryview) -> int:
    """The Modbus CRC-16 of ``data`` as a number (e.g. 0x1241 for ``02 07``)."""
    pairs = _PAIRS
    crc = 0xFFFF
    n = len(data)
    if n < 256:  # a frame (at most 256 bytes): its words in one unpack
        for w in _UNPACK[n >> 1](data):
            crc = pairs[crc ^ w]
    else:
        start = 0
        while n - start >= 256:  # longer than a frame: a block of 128 pairs at a time
            for w in _UNPACK[128](data, start):
                crc = pairs[crc ^ w]
            start += 256
        for w in _UNPACK[(n - start) >> 1](data, start):
            crc = pairs[crc ^ w]
    if n & 1:
        crc = (crc >> 8) ^ _TABLE[(crc ^ data[n - 1]) & 0xFF]
    return crc


def crc16(data: bytes | bytearray | memoryview) -> bytes:
    """The two CRC bytes of ``data`` in wire order (low byte first)."""
    return crc16_value(data).to_bytes(2, "little")


def frame(address: int, pdu: bytes) -> bytes:
    """An RTU frame for ``pdu`` addressed to ``address``."""
    key = (address, pdu)
    adu = _FRAMES.get(key) if type(pdu) is bytes else None
    if adu is None:
        body = bytes((address,)) + pdu
        adu = body + crc16(body)
        if type(pdu) is bytes:
            if len(_FRAMES) >= _FRAMES_MAX:
                _FRAMES.clear()
            _FRAMES[key] = adu
    return adu


def crc_ok(adu: bytes | bytearray | memoryview) -> bool:
    """True if the last two bytes of ``adu`` are the CRC of the rest: then the CRC of the
    whole frame, its own CRC included, is 0 (it is sent low byte first, as the register
    shifts), so no slice and no comparison of the two bytes are needed."""
    return len(adu) >= 4 and crc16_value(adu) == 0
