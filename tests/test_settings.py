"""Line settings validation and the timing calculator."""

from __future__ import annotations

import pytest
from pydantic import ValidationError

from drivebus import LineSettings
from drivebus.errors import ConfigError
from drivebus.timing import switch_silence, timing


def test_defaults_are_modbus_defaults() -> None:
    s = LineSettings()
    assert (s.baudrate, s.bytesize, s.parity, s.stopbits) == (19200, 8, "E", 1)
    assert str(s) == "19200 8E1"


@pytest.mark.parametrize(
    ("text", "expected"),
    [("9600 8N1", (9600, 8, "N", 1)), ("19200-8e1", (19200, 8, "E", 1)),
     ("38400/8N2", (38400, 8, "N", 2)), ("115200 8O1", (115200, 8, "O", 1))],
)
def test_parse(text: str, expected: tuple[int, int, str, int]) -> None:
    s = LineSettings.parse(text)
    assert (s.baudrate, s.bytesize, s.parity, s.stopbits) == expected


@pytest.mark.parametrize(
    ("kwargs", "field"),
    [({"baudrate": 0}, "baudrate"), ({"parity": "X"}, "parity"), ({"stopbits": 3}, "stopbits"),
     ({"bytesize": 9}, "bytesize"), ({"baud": 9600}, "baud"), ({"baudrate": 9600.5}, "baudrate"),
     ({"baudrate": True}, "baudrate"), ({"stopbits": True}, "stopbits")],
)
def test_bad_values_name_the_field(kwargs: dict[str, object], field: str) -> None:
    """A ConfigError (not pydantic's ValidationError) naming the field and the value."""
    with pytest.raises(ConfigError) as exc:
        LineSettings(**kwargs)  # type: ignore[arg-type]
    assert not isinstance(exc.value, ValidationError)
    text = str(exc.value)
    assert field in text and repr(next(iter(kwargs.values()))) in text


def test_parse_errors() -> None:
    with pytest.raises(ConfigError, match="not understood"):
        LineSettings.parse("fast")
    with pytest.raises(ConfigError, match="no baud rate"):
        LineSettings.parse("8N1")
    assert LineSettings.parse("8N1", baudrate=4800).baudrate == 4800


@pytest.mark.parametrize(
    ("fmt", "bits"), [("9600 8N1", 10), ("9600 8E1", 11), ("9600 8O1", 11), ("9600 8N2", 11)]
)
def test_character_bits(fmt: str, bits: int) -> None:
    t = timing(LineSettings.parse(fmt))
    assert t.bits_per_char == bits
    assert t.char_time == pytest.approx(bits / 9600)
    assert t.t35 == pytest.approx(3.5 * bits / 9600)
    assert t.t15 == pytest.approx(1.5 * bits / 9600)


def test_fixed_silences_above_19200() -> None:
    assert timing(LineSettings.parse("19200 8E1")).t35 == pytest.approx(3.5 * 11 / 19200)
    for baud in (38400, 115200):
        t = timing(LineSettings.parse(f"{baud} 8N1"))
        assert (t.t35, t.t15) == (1.75e-3, 0.75e-3)


def test_switch_silence_takes_the_slower_setting() -> None:
    slow, fast = LineSettings.parse("9600 8E1"), LineSettings.parse("115200 8N1")
    assert switch_silence(fast, slow) == switch_silence(slow, fast) == timing(slow).t35
    assert switch_silence(fast, fast) == 1.75e-3
    assert switch_silence(None, slow) == timing(slow).t35


def test_wire_limit_of_a_transaction() -> None:
    t = timing(LineSettings.parse("9600 8N1"))
    # 8-byte request + 9-byte reply at 10 bits/char, 1 ms turnaround, t3.5
    assert t.transaction_time(8, 9, 0.001) == pytest.approx(17 * 10 / 9600 + 0.001 + 35 / 9600)
