"""Simulated Modbus slaves: the base every simulated drive builds on, and faults to inject."""

from __future__ import annotations

import enum
import struct
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field
from typing import ClassVar

from drivebus.pdu import (
    MAX_READ,
    MAX_WRITE,
    READ_HOLDING,
    READ_INPUT,
    WRITE_MULTIPLE,
    WRITE_SINGLE,
    request_length,
)
from drivebus.settings import LineSettings
from drivebus.sim.registers import ExceptionCodes, RegisterSpec, SlaveException

__all__ = ["Fault", "FaultPlan", "RegisterSlave", "SimSlave", "SlaveException"]


class Fault(enum.Enum):
    """Faults a simulated slave can be told to commit on its next replies."""

    NO_REPLY = "no_reply"
    CRC_DAMAGE = "crc_damage"
    GARBAGE = "garbage"
    """Junk bytes (the value, or ff 00 55) go out right before the reply."""
    SLOW_REPLY = "slow_reply"
    """The reply comes ``value`` seconds later than the turnaround."""
    WRONG_ADDRESS = "wrong_address"
    """The reply carries address ``value`` (default: the next address)."""
    POWER_LOSS = "power_loss"


@dataclass
class _Armed:
    fault: Fault
    remaining: int | None  # None: until cleared
    value: float | int | bytes | None


@dataclass
class FaultPlan:
    """Faults armed on one slave; each applies to its next ``times`` replies."""

    armed: list[_Armed] = field(default_factory=list)

    def inject(
        self, fault: Fault, *, times: int | None = 1, value: float | int | bytes | None = None
    ) -> None:
        """Arm ``fault`` for the next ``times`` requests (None: until ``clear``)."""
        self.armed.append(_Armed(fault, times, value))

    def clear(self, fault: Fault | None = None) -> None:
        """Disarm one kind of fault, or all."""
        self.armed = [a for a in self.armed if fault is not None and a.fault is not fault]

    def active(self, fault: Fault) -> bool:
        """True while ``fault`` is armed."""
        return any(a.fault is fault for a in self.armed)

    def take(self) -> dict[Fault, float | int | bytes | None]:
        """The faults that apply to this reply (counting them down)."""
        now: dict[Fault, float | int | bytes | None] = {}
        keep = []
        for a in self.armed:
            now[a.fault] = a.value
            if a.remaining is not None:
                a.remaining -= 1
                if a.remaining <= 0:
                    continue
            keep.append(a)
        self.armed = keep
        return now


class SimSlave:
    """A simulated slave on a virtual wire: address, line settings, turnaround, faults.

    It answers FC03/FC04/FC06/FC16 from its ``register_map``: a subclass lists its
    registers there and gives their values (``read_register``) and what a write does
    (``write_register``), or replaces ``read_registers``/``write_registers`` whole, or
    ``answer``/``request_length`` for non-standard frames. A refusal is answered with the
    slave's ``exception_codes``.
    """

    register_map: ClassVar[Mapping[int, RegisterSpec]] = {}
    """The registers this kind of slave has, by address."""
    exception_codes: ClassVar[ExceptionCodes] = ExceptionCodes()
    """The exception code this kind of slave answers for each kind of refusal."""
    read_functions: ClassVar[frozenset[int]] = frozenset((READ_HOLDING, READ_INPUT))
    """The function codes it reads registers with (any other but FC06/FC16 is refused)."""
    max_read: ClassVar[int] = MAX_READ
    """The most registers one request may read."""

    def __init__(
        self,
        address: int,
        settings: LineSettings | None = None,
        *,
        turnaround: float = 0.001,
    ) -> None:
        if not 1 <= address <= 255:  # 248..255: Modbus TCP unit ids (the machine file's
            # checks keep an RTU line's to 1..247)
            raise ValueError(f"slave address {address} is outside 1..255")
        self.address = address
        self.settings = settings or LineSettings()
        self.turnaround = turnaround
        self.faults = FaultPlan()
        self.requests = 0
        self.crc_errors = 0
        self.crc_error_reply = True
        """Answer a frame with a bad CRC with ``exception_codes.crc`` (where the slave has
        such a code) rather than stay silent."""

    @property
    def powered(self) -> bool:
        """False while a POWER_LOSS fault is armed: the slave hears nothing."""
        return not self.faults.active(Fault.POWER_LOSS)

    def request_length(self, pdu: bytes) -> int | None:
        """Length of the request PDU being received (standard Modbus by default)."""
        return request_length(pdu)

    def on_bad_crc(self, adu: bytes) -> bytes | None:
        """Reply PDU for a frame with a bad CRC: silence, or the slave's CRC exception."""
        self.crc_errors += 1
        code = self.exception_codes.crc
        if code is None or not self.crc_error_reply or len(adu) < 2:
            return None
        return bytes((adu[1] | 0x80, code))

    def handle_pdu(self, pdu: bytes, now: float) -> bytes | None:
        """Answer one request PDU received at ``now``; a refusal becomes an exception reply."""
        self.requests += 1
        try:
            self.advance(now)
            return self.answer(pdu, now)
        except SlaveException as exc:
            return bytes((pdu[0] | 0x80, exc.code))

    def advance(self, now: float) -> None:
        """Bring the slave's state up to ``now`` before a request is answered.

        Simulated drives compute their state lazily: they run the events (switch edges,
        ends of ramps, timers) that happened since the last request here.
        """

    def answer(self, pdu: bytes, now: float) -> bytes:
        """The reply PDU to an FC03/FC04/FC06/FC16 request; SlaveException to refuse it."""
        function = pdu[0]
        if function in self.read_functions:
            address, count = struct.unpack_from(">HH", pdu, 1)
            self.check_count(count)
            values = self.read_registers(function, address, count, now)
            return bytes((function, 2 * count)) + struct.pack(f">{count}H", *values)
        if function == WRITE_SINGLE:
            address, value = struct.unpack_from(">HH", pdu, 1)
            self.write_registers(address, [value], now)
            return pdu[:5]
        if function == WRITE_MULTIPLE:
            address, count = struct.unpack_from(">HH", pdu, 1)
            if not 1 <= count <= MAX_WRITE or pdu[5] != 2 * count:
                raise SlaveException(self.exception_codes.value)
            values = list(struct.unpack_from(f">{count}H", pdu, 6))
            self.write_registers(address, values, now)
            return pdu[:5]
        raise SlaveException(self.exception_codes.function)

    def check_count(self, count: int) -> None:
        """Refuse a read of no registers or of more than ``max_read``."""
        if not 1 <= count <= self.max_read:
            raise SlaveException(self.exception_codes.count)

    def register(self, address: int) -> RegisterSpec:
        """The spec of register ``address``; an address not in the map is refused."""
        spec = self.register_map.get(address)
        if spec is None:
            raise SlaveException(self.exception_codes.address)
        return spec

    def read_registers(self, function: int, address: int, count: int, now: float) -> list[int]:
        """Values of ``count`` registers from ``address`` at time ``now``."""
        words = []
        for a in range(address, address + count):
            self.register(a).check_read(self.exception_codes)
            words.append(self.read_register(a, now) & 0xFFFF)
        return words

    def read_register(self, address: int, now: float) -> int:
        """The value of mapped, readable register ``address`` at ``now``."""
        raise NotImplementedError(f"{type(self).__name__} maps registers but cannot read them")

    def write_registers(self, address: int, values: list[int], now: float) -> None:
        """Check the whole write first (all or nothing), then apply it register by register."""
        self.check_write(address, values)
        for offset, word in enumerate(values):
            self.write_register(address + offset, word, now)

    def check_write(self, address: int, values: list[int]) -> None:
        """Refuse the write of ``values`` from ``address`` if any register refuses its word."""
        for offset, word in enumerate(values):
            self.check_word(address + offset, word)

    def check_word(self, address: int, word: int) -> int:
        """The value a write of ``word`` to ``address`` sets (access and range checked)."""
        return self.register(address).check_write(word, self.exception_codes)

    def write_register(self, address: int, word: int, now: float) -> None:
        """Apply the checked write of ``word`` to register ``address`` at ``now``."""
        raise NotImplementedError(f"{type(self).__name__} maps registers but cannot write them")


class RegisterSlave(SimSlave):
    """A plain register bank: every address in ``size`` reads and writes (tests, bench)."""

    def __init__(
        self,
        address: int,
        settings: LineSettings | None = None,
        *,
        size: int = 1024,
        turnaround: float = 0.001,
        initial: Iterable[tuple[int, int]] = (),
    ) -> None:
        super().__init__(address, settings, turnaround=turnaround)
        self.registers = [0] * size
        for a, v in initial:
            self.registers[a] = v
        self.writes: list[tuple[int, list[int]]] = []

    def read_registers(self, function: int, address: int, count: int, now: float) -> list[int]:
        """Read from the bank; past its end is exception 02."""
        if address + count > len(self.registers):
            raise SlaveException(2)
        return self.registers[address : address + count]

    def write_registers(self, address: int, values: list[int], now: float) -> None:
        """Write into the bank and remember the write."""
        if address + len(values) > len(self.registers):
            raise SlaveException(2)
        self.registers[address : address + len(values)] = values
        self.writes.append((address, list(values)))
