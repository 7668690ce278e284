"""RTU framing: CRC-16 and application data units (address + PDU + CRC)."""

from __future__ import annotations

__all__ = ["crc16", "crc_ok", "frame"]


def _table() -> tuple[int, ...]:
    out = []
    for byte in range(256):
        crc = byte
        for _ in range(8):
            crc = (crc >> 1) ^ 0xA001 if crc & 1 else crc >> 1
        out.append(crc)
    return tuple(out)


_TABLE = _table()
"""CRC-16/MODBUS (reflected polynomial 0xA001) for each byte value."""

_FRAMES: dict[tuple[int, bytes], bytes] = {}
"""Frames built so far, by address and PDU: a poll sends the same few frames again and
again, so its CRC is computed once."""
_FRAMES_MAX = 4096


def _crc(data: bytes | bytearray | memoryview) -> int:
    crc = 0xFFFF
    table = _TABLE
    for b in data:
        crc = (crc >> 8) ^ table[(crc ^ b) & 0xFF]
    return crc


def crc16(data: bytes | bytearray | memoryview) -> bytes:
    """The two CRC bytes of ``data`` in wire order (low byte first)."""
    return _crc(data).to_bytes(2, "little")


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
    """True if the last two bytes of ``adu`` are the CRC of the rest."""
    n = len(adu)
    return n >= 4 and _crc(memoryview(adu)[: n - 2]) == adu[n - 2] | adu[n - 1] << 8
