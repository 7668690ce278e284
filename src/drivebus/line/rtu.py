"""RTU framing: CRC-16 and application data units (address + PDU + CRC)."""

from __future__ import annotations

from pymodbus.framer.rtu import FramerRTU

__all__ = ["crc16", "crc_ok", "frame"]

_compute = FramerRTU.compute_CRC  # pymodbus returns the CRC byte-swapped, i.e. wire order


def crc16(data: bytes) -> bytes:
    """The two CRC bytes of ``data`` in wire order (low byte first)."""
    return _compute(data).to_bytes(2, "big")


def frame(address: int, pdu: bytes) -> bytes:
    """An RTU frame for ``pdu`` addressed to ``address``."""
    body = bytes((address,)) + pdu
    return body + crc16(body)


def crc_ok(adu: bytes) -> bool:
    """True if the last two bytes of ``adu`` are the CRC of the rest."""
    return len(adu) >= 4 and crc16(adu[:-2]) == adu[-2:]
