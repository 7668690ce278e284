"""The RTU CRC-16 of our own: the Modbus spec's examples, the manuals' frames, and pymodbus."""

from __future__ import annotations

import importlib

import pytest
from hypothesis import given
from hypothesis import strategies as st

from drivebus.line.rtu import crc16, crc16_value, crc_ok, frame


def hx(s: str) -> bytes:
    return bytes.fromhex(s)


def _bitwise_crc(data: bytes) -> int:
    """The spec's bit-by-bit CRC procedure (MODBUS over Serial Line v1.02, 6.2.2), literally."""
    crc = 0xFFFF
    for byte in data:
        crc ^= byte
        for _ in range(8):
            lsb = crc & 1
            crc >>= 1
            if lsb:
                crc ^= 0xA001
    return crc


def _pymodbus_crc() -> object:
    """pymodbus's CRC function, wherever its version keeps it (a third-party reference)."""
    for module, name in (
        ("pymodbus.framer.rtu", "FramerRTU.compute_CRC"),  # 3.7 ..
        ("pymodbus.message.rtu", "MessageRTU.compute_CRC"),  # 3.6
        ("pymodbus.utilities", "computeCRC"),  # 3.0 .. 3.5
    ):
        try:
            obj: object = importlib.import_module(module)
        except ImportError:
            continue
        for part in name.split("."):
            obj = getattr(obj, part, None)
        if obj is not None:
            return obj
    pytest.fail("pymodbus (a test dependency) has no CRC function where 3.0-3.16 keep it")


def test_the_specs_example() -> None:
    # MODBUS over Serial Line v1.02, appendix B: the CRC of 02 07 is 0x1241, sent 41 12.
    assert crc16_value(hx("02 07")) == 0x1241
    assert crc16(hx("02 07")) == hx("41 12")
    assert frame(2, hx("07")) == hx("02 07 41 12")


@pytest.mark.parametrize(
    "adu",
    [
        "01 03 00 00 00 0A C5 CD",  # read 10 holding registers from slave 1
        "11 03 00 6B 00 03 76 87",  # Modicon PI-MBUS-300's read holding registers example
        "01 06 00 12 00 00 29 CF",  # NT86 manual, appendix A
        "01 10 00 4B 00 04 08 00 64 00 64 02 58 01 F4 86 EC",  # NT86 manual, appendix A
        "01 03 0A 00 00 00 01 00 00 00 03 FF FF C5 C6",  # an NT86 status reply
    ],
)
def test_known_frames(adu: str) -> None:
    data = hx(adu)
    assert crc16(data[:-2]) == data[-2:]
    assert crc_ok(data)
    assert crc_ok(bytearray(data)) and crc_ok(memoryview(data))


def test_damage_is_seen() -> None:
    good = hx("01 06 00 12 00 00 29 CF")
    assert not crc_ok(good[:-1] + b"\xce")
    assert not crc_ok(b"\x02" + good[1:])  # another address, same CRC
    assert not crc_ok(good[:3])  # too short to be a frame


def test_the_crc_runs_in_c() -> None:
    """crcmod-plus's C extension computes it here (its wheels carry it): without it the
    reply check per transaction would run in Python, three times slower."""
    import crcmod.crcmod

    assert crcmod.crcmod._usingExtension, "crcmod-plus runs without its C extension"


def test_empty_input_is_the_initial_value() -> None:
    assert crc16_value(b"") == 0xFFFF


@given(st.binary(max_size=600))
def test_matches_the_bitwise_procedure(data: bytes) -> None:
    # (longer than a frame too; and the receiver checks its bytearray buffer in place)
    assert crc16_value(data) == _bitwise_crc(data)
    assert crc16_value(bytearray(data)) == crc16_value(memoryview(data)) == _bitwise_crc(data)


@given(st.binary(max_size=256))
def test_matches_pymodbus(data: bytes) -> None:
    theirs = _pymodbus_crc()
    # pymodbus returns the CRC with its bytes swapped: its big-endian bytes are wire order
    assert crc16(data) == theirs(data).to_bytes(2, "big")  # type: ignore[operator]
