"""Simulated Modbus slaves: the base every simulated drive builds on, and faults to inject."""

from __future__ import annotations

import enum
import struct
from collections.abc import Iterable
from dataclasses import dataclass, field

from drivebus import pdu as P
from drivebus.settings import LineSettings

__all__ = ["Fault", "FaultPlan", "RegisterSlave", "SimSlave", "SlaveException"]


class SlaveException(Exception):
    """Raised inside a simulated slave to answer with Modbus exception ``code``."""

    def __init__(self, code: int) -> None:
        super().__init__(code)
        self.code = code


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

    Subclasses answer register reads and writes (``read_registers``/``write_registers``),
    or replace ``handle_pdu``/``request_length`` for non-standard frames.
    """

    def __init__(
        self,
        address: int,
        settings: LineSettings | None = None,
        *,
        turnaround: float = 0.001,
    ) -> None:
        if not 1 <= address <= 247:
            raise ValueError(f"slave address {address} is outside 1..247")
        self.address = address
        self.settings = settings or LineSettings()
        self.turnaround = turnaround
        self.faults = FaultPlan()
        self.requests = 0
        self.crc_errors = 0

    @property
    def powered(self) -> bool:
        """False while a POWER_LOSS fault is armed: the slave hears nothing."""
        return not self.faults.active(Fault.POWER_LOSS)

    def request_length(self, pdu: bytes) -> int | None:
        """Length of the request PDU being received (standard Modbus by default)."""
        return P.request_length(pdu)

    def on_bad_crc(self, adu: bytes) -> bytes | None:
        """Reply PDU for a frame with a bad CRC; standard slaves stay silent."""
        self.crc_errors += 1
        return None

    def handle_pdu(self, pdu: bytes, now: float) -> bytes | None:
        """Answer one request PDU; exceptions become Modbus exception replies."""
        self.requests += 1
        fc = pdu[0]
        try:
            if fc in (P.READ_HOLDING, P.READ_INPUT):
                address, count = struct.unpack_from(">HH", pdu, 1)
                if not 1 <= count <= P.MAX_READ:
                    raise SlaveException(3)
                values = self.read_registers(fc, address, count, now)
                return bytes((fc, 2 * count)) + struct.pack(f">{count}H", *values)
            if fc == P.WRITE_SINGLE:
                address, value = struct.unpack_from(">HH", pdu, 1)
                self.write_registers(address, [value], now)
                return pdu[:5]
            if fc == P.WRITE_MULTIPLE:
                address, count = struct.unpack_from(">HH", pdu, 1)
                if not 1 <= count <= P.MAX_WRITE or pdu[5] != 2 * count:
                    raise SlaveException(3)
                values = list(struct.unpack_from(f">{count}H", pdu, 6))
                self.write_registers(address, values, now)
                return pdu[:5]
            raise SlaveException(1)
        except SlaveException as exc:
            return bytes((fc | 0x80, exc.code))

    def read_registers(self, function: int, address: int, count: int, now: float) -> list[int]:
        """Values of ``count`` registers from ``address`` at time ``now``."""
        raise SlaveException(2)

    def write_registers(self, address: int, values: list[int], now: float) -> None:
        """Apply a write of ``values`` from ``address`` at time ``now``."""
        raise SlaveException(2)


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
