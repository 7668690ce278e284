"""Register tools: read and write raw registers of one slave, like mbpoll, in drive terms.

Register addresses are the 0-based PDU addresses the drive manuals print (mbpoll's
``-0 -r REG``, or ``-r REG+1`` without ``-0``). Values are shown and taken in one of the
``FORMATS``: 16-bit words as ``hex``, ``int`` (signed) or ``uint``; pairs of words as
32-bit ``int32-le``/``int32-be`` (low or high word first) or ``float`` (IEEE 754, high word
first, as mbpoll's ``-B``).
"""

from __future__ import annotations

import math
import struct
from collections.abc import AsyncIterator, Sequence
from contextlib import AsyncExitStack, asynccontextmanager
from dataclasses import dataclass
from typing import Literal

from drivebus import checks
from drivebus.app.targets import Target, parse_target
from drivebus.bus import Bus, Priority, SlaveHandle
from drivebus.errors import ArgumentError
from drivebus.motion.lines import make_line
from drivebus.settings import LineSettings

__all__ = [
    "FORMATS",
    "RegisterValues",
    "decode",
    "encode",
    "open_slave",
    "read_registers",
    "write_registers",
]

Format = Literal["hex", "int", "uint", "int32-le", "int32-be", "float"]
FORMATS: tuple[Format, ...] = ("hex", "int", "uint", "int32-le", "int32-be", "float")
_WIDE = ("int32-le", "int32-be", "float")


def _check_format(fmt: str) -> Format:
    for known in FORMATS:
        if fmt == known:
            return known
    raise ArgumentError(f"--format: {fmt!r} is not one of {', '.join(FORMATS)}")


def words_per_value(fmt: str) -> int:
    """Registers one value of ``fmt`` takes (1 or 2)."""
    return 2 if _check_format(fmt) in _WIDE else 1


def decode(words: Sequence[int], fmt: str) -> list[int | float | str]:
    """Register words as values of ``fmt`` (an odd word left over by a 32-bit format is an
    ``ArgumentError``)."""
    fmt = _check_format(fmt)
    if fmt == "hex":
        return [f"0x{w:04X}" for w in words]
    if fmt == "uint":
        return list(words)
    if fmt == "int":
        return [w - 0x10000 if w & 0x8000 else w for w in words]
    if len(words) % 2:
        raise ArgumentError(f"--format {fmt}: takes pairs of registers, not {len(words)}")
    out: list[int | float | str] = []
    for lo_first in range(0, len(words), 2):
        a, b = words[lo_first], words[lo_first + 1]
        hi, lo = (b, a) if fmt == "int32-le" else (a, b)
        raw = (hi << 16) | lo
        if fmt == "float":
            out.append(struct.unpack(">f", raw.to_bytes(4, "big"))[0])
        else:
            out.append(raw - (1 << 32) if raw & 0x80000000 else raw)
    return out


_FLOAT32_MAX = struct.unpack(">f", bytes.fromhex("7f7fffff"))[0]
"""The largest finite 32-bit float."""


def encode(values: Sequence[str | int | float], fmt: str) -> list[int]:
    """Values (as typed on a command line, or numbers) as register words in ``fmt``."""
    fmt = _check_format(fmt)
    words: list[int] = []
    for i, text in enumerate(values):
        name = f"VALUE {i + 1}"
        if fmt == "float":
            v = checks.finite(name, _number(text, name, float))
            try:
                packed = struct.pack(">f", v)
            except OverflowError:
                raise ArgumentError(f"{name}: {text} is beyond what format float holds (a "
                                    f"32-bit float: -{_FLOAT32_MAX:.8g}..{_FLOAT32_MAX:.8g})"
                                    ) from None
            hi, lo = struct.unpack(">HH", packed)
            words += [hi, lo]
            continue
        n = _number(text, name, int)
        if fmt in ("int32-le", "int32-be"):
            n = checks.whole(name, n, -(1 << 31), (1 << 32) - 1)
            u = n & 0xFFFFFFFF
            hi, lo = u >> 16, u & 0xFFFF
            words += [lo, hi] if fmt == "int32-le" else [hi, lo]
        elif fmt == "int":
            words.append(checks.whole(name, n, -0x8000, 0xFFFF) & 0xFFFF)
        else:
            words.append(checks.whole(name, n, 0, 0xFFFF))
    return words


def _number(text: str | int | float, name: str, kind: type) -> int | float:
    if isinstance(text, int | float) and not isinstance(text, bool):
        return text
    s = str(text).strip()
    try:
        if kind is int:
            return int(s, 0)  # 0x1F, 0b101, 42
        v = float(s)
    except ValueError:
        raise ArgumentError(f"{name}: {text!r} is not a number") from None
    if not math.isfinite(v):
        raise ArgumentError(f"{name}: {text!r} is not a finite number")
    return v


@dataclass(frozen=True)
class RegisterValues:
    """What a read returned: where from, the words, and the values in a format."""

    target: str
    address: int
    register: int
    input: bool
    words: list[int]
    format: str
    values: list[int | float | str]

    def as_dict(self) -> dict[str, object]:
        """JSON-ready data."""
        return {
            "target": self.target, "address": self.address, "register": self.register,
            "table": "input" if self.input else "holding", "words": self.words,
            "format": self.format, "values": self.values,
        }


@asynccontextmanager
async def open_slave(
    target: str | Target,
    address: int,
    *,
    settings: LineSettings | None = None,
    timeout: float = 0.5,
    retries: int = 1,
    broadcast: bool = False,
) -> AsyncIterator[SlaveHandle]:
    """A slave handle on ``target`` for the block (the line is opened and closed here);
    ``broadcast``: address 0 (every slave, no reply) is allowed."""
    t = parse_target(target) if isinstance(target, str) else target
    address = checks.whole("ADDR", address, 0 if t.kind == "tcp" or broadcast else 1,
                           255 if t.kind == "tcp" else 247)
    config = t.line_config(settings, timeout=timeout, retries=retries)
    async with AsyncExitStack() as stack:
        bus = await stack.enter_async_context(
            Bus(make_line(config), timeout=timeout, retries=retries)
        )
        yield bus.slave(address)


async def read_registers(
    slave: SlaveHandle, register: int, count: int, *, input: bool = False,
    fmt: str = "uint",
) -> tuple[list[int], list[int | float | str]]:
    """Read ``count`` values of ``fmt`` from ``register`` (FC03, or FC04 with ``input``):
    the words and the values."""
    n = checks.whole("COUNT", count, 1, 125) * words_per_value(fmt)
    if n > 125:
        raise ArgumentError(f"COUNT: {count} values of {fmt} are {n} registers, more than "
                            f"one read carries (125)")
    read = slave.read_input_registers if input else slave.read_holding_registers
    words = await read(register, n, priority=Priority.COMMAND)
    return words, decode(words, fmt)


async def write_registers(
    slave: SlaveHandle, register: int, values: Sequence[str | int | float], *,
    fmt: str = "uint",
) -> list[int]:
    """Write ``values`` (in ``fmt``) from ``register``: one word with FC06, more with FC16
    (never retried: a write may be a command). Returns the words written."""
    if not values:
        raise ArgumentError("VALUE: give at least one value to write")
    words = encode(values, fmt)
    if len(words) == 1:
        await slave.write_register(register, words[0], priority=Priority.COMMAND,
                                   idempotent=False)
    else:
        await slave.write_registers(register, words, priority=Priority.COMMAND,
                                    idempotent=False)
    return words
