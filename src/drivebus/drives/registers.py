"""The one register codec: typed register definitions and 16/32-bit value encoding."""

from __future__ import annotations

import enum
from dataclasses import dataclass

from drivebus.errors import ConfigError, LimitViolation

__all__ = ["Access", "Register", "WordOrder", "join_words", "split_words"]


class WordOrder(enum.Enum):
    """Which 16-bit word of a 32-bit value sits at the lower register address."""

    LOW_FIRST = "low_first"
    HIGH_FIRST = "high_first"


class Access(enum.Enum):
    """What the drive allows on a register."""

    R = "R"
    W = "W"
    RW = "RW"


def split_words(value: int, order: WordOrder) -> list[int]:
    """A 32-bit value (two's complement if negative) as two words in ``order``."""
    u = value & 0xFFFFFFFF
    hi, lo = u >> 16, u & 0xFFFF
    return [lo, hi] if order is WordOrder.LOW_FIRST else [hi, lo]


def join_words(words: list[int], order: WordOrder, *, signed: bool) -> int:
    """The 32-bit value of two words in ``order``."""
    if order is WordOrder.LOW_FIRST:
        lo, hi = words
    else:
        hi, lo = words
    u = (hi << 16) | lo
    if signed and u & 0x80000000:
        u -= 1 << 32
    return u


@dataclass(frozen=True)
class Register:
    """One drive parameter: where it is, how wide, signed or not, its unit and range.

    A 32-bit register normally occupies ``address`` and ``address + 1`` in ``order``;
    where a drive keeps the halves apart (CL86R's tables), ``low_address`` names the
    low word's register and ``address`` is the high word's.
    """

    name: str
    address: int
    words: int = 1
    signed: bool = False
    order: WordOrder = WordOrder.HIGH_FIRST
    unit: str = ""
    minimum: int | None = None
    maximum: int | None = None
    access: Access = Access.RW
    low_address: int | None = None
    objects: bool = False
    """Its address is its object's own (an object-addressed map): its words go with that
    one address, and the register at the next address is another object, not its next
    word."""
    offset: int = 0
    """In an object-addressed map, the words of the object before it (a sub-index behind
    the object's address): a read of it reads the object from its address."""

    def __post_init__(self) -> None:
        if self.words not in (1, 2):
            raise ConfigError(f"register {self.name}: width must be 1 or 2 words")

    @property
    def position(self) -> int:
        """Where its first word sits in a request from its address (``offset``)."""
        return self.offset

    def follows(self, before: Register) -> bool:
        """True if one request can carry ``before`` and then this register: the next
        words of the same object, or (in a flat word map) the next address."""
        if self.objects or before.objects:
            return self.objects and before.objects and self.address == before.address and \
                self.offset == before.offset + before.words
        return before.contiguous and self.contiguous and \
            self.address == before.address + before.words

    @property
    def lo(self) -> int:
        """Smallest value the register can hold (its documented range, else its width)."""
        if self.minimum is not None:
            return self.minimum
        bits = 16 * self.words
        return -(1 << (bits - 1)) if self.signed else 0

    @property
    def hi(self) -> int:
        """Largest value the register can hold."""
        if self.maximum is not None:
            return self.maximum
        bits = 16 * self.words
        return (1 << (bits - 1)) - 1 if self.signed else (1 << bits) - 1

    @property
    def contiguous(self) -> bool:
        """True if the register's words can be read or written in one transaction."""
        return self.words == 1 or self.low_address is None

    def check(self, value: int) -> int:
        """``value`` as an int if it is in range; else ``LimitViolation`` naming the register."""
        v = int(value)
        if v != value:
            raise LimitViolation(
                f"register {self.name} ({self.address}) takes whole numbers, not {value}"
            )
        if not self.lo <= v <= self.hi:
            unit = f" {self.unit}" if self.unit else ""
            raise LimitViolation(
                f"value {v}{unit} for register {self.name} (address {self.address}) is outside "
                f"its range {self.lo}..{self.hi}{unit}"
            )
        return v

    def encode(self, value: int) -> list[int]:
        """Words to write for ``value`` (range-checked), in register-address order."""
        v = self.check(value)
        if self.words == 1:
            return [v & 0xFFFF]
        return split_words(v, self.order)

    def decode(self, words: list[int]) -> int:
        """The value of the register's words, as read in register-address order."""
        if self.words == 1:
            w = words[0]
            return w - 0x10000 if self.signed and w & 0x8000 else w
        return join_words(list(words[:2]), self.order, signed=self.signed)
