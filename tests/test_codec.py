"""PDU codec, RTU framing and the register codec, against the manuals and pymodbus."""

from __future__ import annotations

import pytest
from hypothesis import given
from hypothesis import strategies as st
from pymodbus.pdu.register_message import (
    ReadHoldingRegistersRequest,
    ReadInputRegistersRequest,
    WriteMultipleRegistersRequest,
    WriteSingleRegisterRequest,
)

from drivebus import pdu as P
from drivebus.drives.registers import Register, WordOrder, join_words, split_words
from drivebus.errors import ArgumentError, FrameError, LimitViolation, ModbusException
from drivebus.line.rtu import crc16, crc_ok, frame


def hx(s: str) -> bytes:
    return bytes.fromhex(s)


@pytest.mark.parametrize(
    ("address", "pdu", "expected"),
    [
        # NT86 manual, Appendix A (CRC-valid examples)
        (1, P.write_single_request(0x12, 0), "01 06 00 12 00 00 29 CF"),
        (1, P.write_multiple_request(0x4B, [100, 100, 600, 500]),
         "01 10 00 4B 00 04 08 00 64 00 64 02 58 01 F4 86 EC"),
    ],
)
def test_seed_frames_byte_for_byte(address: int, pdu: bytes, expected: str) -> None:
    assert frame(address, pdu) == hx(expected)


def test_crc_known_vectors() -> None:
    assert crc16(hx("01 03 00 00 00 0A")) == hx("C5 CD")
    assert crc_ok(hx("01 06 00 12 00 00 29 CF"))
    assert not crc_ok(hx("01 06 00 12 00 00 29 CE"))


@given(st.integers(0, 0xFFFF - 124), st.integers(1, 125))
def test_read_request_matches_pymodbus(address: int, count: int) -> None:
    ours = P.read_request(P.READ_HOLDING, address, count)
    theirs = ReadHoldingRegistersRequest(address=address, count=count)
    assert ours == bytes((theirs.function_code,)) + theirs.encode()
    ours4 = P.read_request(P.READ_INPUT, address, count)
    theirs4 = ReadInputRegistersRequest(address=address, count=count)
    assert ours4 == bytes((theirs4.function_code,)) + theirs4.encode()


@given(st.integers(0, 0xFF00), st.lists(st.integers(0, 0xFFFF), min_size=1, max_size=123))
def test_write_requests_match_pymodbus(address: int, values: list[int]) -> None:
    ours = P.write_multiple_request(address, values)
    theirs = WriteMultipleRegistersRequest(address=address, registers=values)
    assert ours == bytes((theirs.function_code,)) + theirs.encode()
    one = P.write_single_request(address, values[0])
    theirs1 = WriteSingleRegisterRequest(address=address, registers=[values[0]])
    assert one == bytes((theirs1.function_code,)) + theirs1.encode()


@given(st.lists(st.integers(0, 0xFFFF), min_size=1, max_size=125))
def test_lengths_are_predicted_from_the_first_bytes(values: list[int]) -> None:
    req = P.write_multiple_request(7, values)
    assert P.request_length(req[:6]) == len(req)
    assert P.request_length(req[:5]) is None
    reply = bytes((3, 2 * len(values))) + b"".join(v.to_bytes(2, "big") for v in values)
    assert P.response_length(reply[:1]) is None
    assert P.response_length(reply[:2]) == len(reply)
    assert P.decode_read_reply(reply, 3, len(values), slave=1) == values
    assert P.read_reply_values(reply, P.read_request(3, 9, len(values)), 1) == values


def test_bad_requests_name_the_problem() -> None:
    with pytest.raises(ArgumentError, match=r"register count: 126 is outside 1\.\.125"):
        P.read_request(3, 0, 126)
    with pytest.raises(ArgumentError, match=r"register value: 70000 is outside 0\.\.65535"):
        P.write_single_request(1, 70000)
    with pytest.raises(ArgumentError, match="past 65535"):
        P.read_request(3, 65530, 10)


def test_reply_checks() -> None:
    with pytest.raises(FrameError, match="carries 2 bytes, 4 expected"):
        P.decode_read_reply(hx("03 02 00 01"), 3, 2, slave=1)  # 2 bytes for 2 registers
    read2 = P.read_request(3, 0, 2)
    for reply, error in ((hx("03 02 00 01"), "carries 2 bytes, 4 expected"),
                         (hx("03 04 00 01 00"), "carries 4 bytes, 4 expected"),
                         (hx("04 04 00 01 00 02"), "reply function 0x04 to request 0x03"),
                         (hx("03"), "reply function 0x03 to request 0x03"),
                         (b"", "reply function 0x00 to request 0x03")):
        for decode in (lambda r: P.decode_read_reply(r, 3, 2, slave=1),
                       lambda r: P.read_reply_values(r, read2, 1)):
            with pytest.raises(FrameError, match=error):
                decode(reply)
    with pytest.raises(ModbusException) as exc:
        P.check_exception(hx("83 02"), slave=5, texts={2: "vendor text"})
    assert exc.value.code == 2 and exc.value.function == 3 and "vendor text" in str(exc.value)
    with pytest.raises(FrameError):
        P.decode_write_single_reply(hx("06 00 01 00 02"), hx("06 00 01 00 03"), slave=1)


@pytest.mark.parametrize("order", list(WordOrder))
@given(value=st.integers(-(2**31), 2**31 - 1))
def test_32bit_signed_round_trip(order: WordOrder, value: int) -> None:
    reg = Register("pos", 10, words=2, signed=True, order=order)
    words = reg.encode(value)
    assert all(0 <= w <= 0xFFFF for w in words)
    assert reg.decode(words) == value


@pytest.mark.parametrize(
    ("value", "order", "words"),
    [
        (-1, WordOrder.LOW_FIRST, [0xFFFF, 0xFFFF]),
        (0x12345678, WordOrder.LOW_FIRST, [0x5678, 0x1234]),
        (0x12345678, WordOrder.HIGH_FIRST, [0x1234, 0x5678]),
        (-(2**31), WordOrder.HIGH_FIRST, [0x8000, 0x0000]),
        (2**31 - 1, WordOrder.LOW_FIRST, [0xFFFF, 0x7FFF]),
        (-2, WordOrder.HIGH_FIRST, [0xFFFF, 0xFFFE]),
    ],
)
def test_word_order_by_hand(value: int, order: WordOrder, words: list[int]) -> None:
    assert split_words(value, order) == words
    assert join_words(words, order, signed=True) == value


def test_register_range_errors_name_register_and_range() -> None:
    reg = Register("accel", 70, minimum=1, maximum=3000, unit="r/s²")
    assert reg.encode(3000) == [3000]
    with pytest.raises(LimitViolation, match=r"accel \(address 70\).*1..3000"):
        reg.encode(3001)
    with pytest.raises(LimitViolation, match="outside"):
        Register("pos", 0, words=2, signed=True).encode(2**31)
    assert Register("s", 0, signed=True).decode([0xFFFE]) == -2
