"""What the simulated twins' register maps are made of, and how a simulated slave refuses.

Each twin writes its drive's map out of the manual (independently of the drive's profile,
so that a profile mistake shows up in tests) as ``RegisterSpec`` entries; ``SimSlave``
checks reads and writes against them and answers a refusal with the drive's own
exception code from its ``ExceptionCodes`` (several vendors renumber 01-07).
"""

from __future__ import annotations

from dataclasses import dataclass

from drivebus.drives.registers import Access

__all__ = [
    "Access",
    "ExceptionCodes",
    "RegisterSpec",
    "SlaveException",
    "signed16",
    "signed32",
]


class SlaveException(Exception):
    """Raised inside a simulated slave to answer with Modbus exception ``code``."""

    def __init__(self, code: int) -> None:
        super().__init__(code)
        self.code = code


@dataclass(frozen=True, slots=True)
class ExceptionCodes:
    """The exception code a kind of slave answers for each reason it refuses a request.

    The defaults are the Modbus meanings (01 illegal function, 02 illegal data address,
    03 illegal data value).
    """

    function: int = 1
    """A function code the slave does not serve."""
    address: int = 2
    """An address (or object) that is not in the slave's map."""
    access: int = 2
    """A write to a read-only register, or a read of a write-only one."""
    value: int = 3
    """A value outside the register's range, or an FC16 request whose count is malformed."""
    count: int = 3
    """A read of no registers or of more than the slave serves at once."""
    crc: int | None = None
    """The reply to a frame with a bad CRC; None: silence, as the Modbus spec says."""
    read_access: int | None = None
    """A read of a write-only register, where it differs from ``access`` (the MOONS'
    0x11 "register does not support read" beside 0x12 "does not support write")."""

    @property
    def read_refused(self) -> int:
        """The code of a read of a write-only register (or coil)."""
        return self.access if self.read_access is None else self.read_access


def signed16(word: int) -> int:
    """A 16-bit word read as a two's-complement value."""
    word &= 0xFFFF
    return word - 0x10000 if word & 0x8000 else word


def signed32(value: int) -> int:
    """The low 32 bits of ``value`` read as a two's-complement value."""
    value &= 0xFFFFFFFF
    return value - (1 << 32) if value & 0x80000000 else value


@dataclass(frozen=True, slots=True)
class RegisterSpec:
    """One register (or dictionary object) of a twin's map, as the drive's manual gives it."""

    default: int = 0
    """The factory value (as printed, even where it lies outside the printed range)."""
    minimum: int = 0
    maximum: int = 0xFFFF
    """The range a write must fall in (of the signed value where ``signed``)."""
    access: Access = Access.RW
    """R: writes are refused; W: reads are refused; RW: both allowed."""
    signed: bool = False
    """The word holds a two's-complement 16-bit value."""
    stored: bool = False
    """Kept in the drive's EEPROM or flash; each twin says when a write reaches it."""
    command: bool = False
    """A trigger: a write acts on the drive and is not kept; the register reads back 0."""

    def value(self, word: int) -> int:
        """What the 16-bit ``word`` means in this register."""
        return signed16(word) if self.signed else word

    def check_read(self, codes: ExceptionCodes) -> None:
        """Refuse a read of a write-only register with the drive's code."""
        if self.access is Access.W:
            raise SlaveException(codes.read_refused)

    def check_write(self, word: int, codes: ExceptionCodes) -> int:
        """The value a write of ``word`` sets; a refusal raises the drive's code."""
        if self.access is Access.R:
            raise SlaveException(codes.access)
        value = self.value(word)
        if not self.minimum <= value <= self.maximum:
            raise SlaveException(codes.value)
        return value
