"""A described twin's registers on the wire: reads (stored words, or computed from what a
register *means*), coils and discrete inputs, and writes checked against the map.
"""

from __future__ import annotations

import struct
from typing import Any

from drivebus.drives.description import TWIN_MEANINGS, Reg
from drivebus.drives.units import Kind
from drivebus.drives.values import reg_value
from drivebus.pdu import (
    READ_COILS,
    READ_DISCRETE,
    READ_INPUT,
    WRITE_COIL,
    WRITE_MULTIPLE,
    WRITE_SINGLE,
)
from drivebus.sim.described.base import TwinBase
from drivebus.sim.registers import SlaveException, signed32

_COMPUTED = {"position", "velocity", "command_velocity", "alarm_code", "motion", "inputs",
             "outputs"}


_VALUES = _COMPUTED | {"constant", "address", "direction"}
"""Meanings that are a register's value (the others are a state: 1 or 0)."""


class Registers(TwinBase):
    """Reads and writes of the map: stored, computed and checked values."""

    def read_registers(self, function: int, address: int, count: int, now: float) -> list[int]:
        """Holding registers (FC03), or the description's input registers (FC04)."""
        if function != READ_INPUT:
            self._check_whole(address, count)
            return super().read_registers(function, address, count, now)
        out = []
        for a in range(address, address + count):
            w = self._input_words.get(a)
            if w is None:
                raise SlaveException(self.exception_codes.address)
            raw = self._computed(w.reg, w.index, now) if _computed(w.reg) else \
                w.reg.default_at(w.index)
            words: dict[int, int] = {}
            self._store(words, w.reg, w.index, raw)
            out.append(words[a])
        return out

    def answer(self, pdu: bytes, now: float) -> bytes:
        """Coils (FC01, FC05) and discrete inputs (FC02) where the description has them;
        registers as any twin."""
        function = pdu[0]
        fcs = self.description.link.functions
        if function in (WRITE_SINGLE, WRITE_MULTIPLE) and function not in fcs:
            raise SlaveException(self.exception_codes.function)  # [link] functions: not served
        if function in (READ_COILS, READ_DISCRETE) and function in fcs:
            address, count = struct.unpack_from(">HH", pdu, 1)
            self.check_count(count)
            space = 2 if function == READ_COILS else 3
            states = [self._bit(space, a, now) for a in range(address, address + count)]
            packed = bytearray((count + 7) // 8)
            for i, on in enumerate(states):
                packed[i // 8] |= on << (i % 8)
            return bytes((function, len(packed))) + bytes(packed)
        if function == WRITE_COIL and function in fcs:
            address, value = struct.unpack_from(">HH", pdu, 1)
            w = self._bits.get((2, address))
            if w is None:
                raise SlaveException(self.exception_codes.address)
            if w.reg.d.access == "R":
                raise SlaveException(self.exception_codes.access)
            if value not in (0x0000, 0xFF00):
                raise SlaveException(self.exception_codes.value)
            before = dict(self.coils)
            self.coils[address] = 1 if value else 0
            self._act(w.reg, w.index, now, before)
            return pdu[:5]
        return super().answer(pdu, now)

    def _bit(self, space: int, address: int, now: float) -> int:
        """A coil's or discrete input's state: what it means now, else stored or fixed."""
        w = self._bits.get((space, address))
        if w is None:
            raise SlaveException(self.exception_codes.address)
        if w.reg.d.access == "W":  # a command coil the drive does not read back
            raise SlaveException(self.exception_codes.read_refused)
        means = w.reg.d.means
        signals = self._signals(now)
        if means in signals:
            return int(signals[means])
        return self._raw(w.reg, w.index) & 1

    def read_register(self, address: int, now: float) -> int:
        """A stored word, or one computed now for registers that show the drive's state."""
        w = self._words[address]
        reg = w.reg
        if not _computed(reg):
            return self.regs[address]
        raw = self._computed(reg, w.index, now)
        words: dict[int, int] = {}
        self._store(words, reg, w.index, raw)
        return words[address]

    def _computed(self, reg: Reg, index: int | None, now: float) -> int:
        """The value of a register that shows the drive's state: from what it means, with
        the bits that have meanings set or cleared by the state."""
        means = reg.d.means
        if means == "position":
            counter = signed32(round(self.kin.position(now)))
            value = _clamp(reg, round(counter / reg.codec.scale))
        elif means in ("velocity", "command_velocity"):
            rpm = self.speed_rpm(now)
            if reg.codec.kind is Kind.SPEED:
                value = _clamp(reg, round(rpm / reg.codec.factor(self.pulses_per_rev)
                                          / reg.codec.scale))
            else:
                value = _clamp(reg, round(rpm))
        elif means == "alarm_code":
            value = self.alarm_code
        elif means == "motion":
            value = reg.d.values.get(self.motion or "none", 0)
        elif means == "address":
            value = self.address
        elif means == "direction":
            v = self.kin.velocity(now)
            if v:
                self._last_dir = -1 if v < 0 else 1
            value = int(self._last_dir < 0)
        elif means in TWIN_MEANINGS and means not in _VALUES:
            value = int(bool(self._signals(now).get(means, False)))
        elif means == "inputs":
            value = self._io_word("inputs", now)
        elif means == "outputs":
            value = self._io_word("outputs", now)
        elif means is None and reg.d.access == "R":
            value = 0
        else:
            value = self._raw(reg, index)
        bits = [b for b in reg.d.bits.values() if b.means is not None]
        if bits:
            signals = self._signals(now)
            for b in bits:
                if signals.get(b.means or "", False):
                    value |= b.mask
                else:
                    value &= ~b.mask
        for b in reg.d.bits.values():
            if b.twin is not None:
                value = value | b.mask if self._eval(b.twin, now) else value & ~b.mask
        return value

    def physical(self, reg: Reg, index: int | None, now: float, ref: float | None = None
                 ) -> Any:
        """The physical value register ``reg`` holds (a ramp time as a rate in r/s²)."""
        raw = self._computed(reg, index, now) if _computed(reg) else self._raw(reg, index)
        if reg.codec.kind is Kind.RAMP and isinstance(reg.codec.ramp, str) and ref is None:
            ref_reg = self.description.regs[reg.codec.ramp]
            ref_v = self.physical(ref_reg, index if ref_reg.array else None, now)
            ref = abs(float(ref_v)) or abs(self.speed_rpm(now))
        return reg_value(reg, raw, reg.codec.to_physical(raw, ppr=self.pulses_per_rev,
                                                        ref_rpm=ref))

    def check_write(self, address: int, values: list[int]) -> None:
        """Word by word, then each 32-bit register written whole against its range."""
        if len(values) > self.description.link.max_write:
            raise SlaveException(self.exception_codes.count)
        self._check_whole(address, len(values))
        super().check_write(address, values)
        written = dict(zip(range(address, address + len(values)), values, strict=True))
        for a in written:
            pair = self._pairs.get(a)
            if pair is None:
                continue
            reg, index = pair
            r = reg.at(index)
            low = r.low_address if r.low_address is not None else r.address + 1
            if r.address in written and low in written:
                words = {**self.regs, **written}
                value = self._raw(reg, index, words)
                if (reg.d.min is not None and value < reg.d.min) or \
                        (reg.d.max is not None and value > reg.d.max):
                    raise SlaveException(self.exception_codes.value)

    def write_registers(self, address: int, values: list[int], now: float) -> None:
        """Store the words, then act on the registers written (in address order)."""
        self.check_write(address, values)
        before = dict(self.regs)
        touched: list[tuple[Reg, int | None]] = []
        write_through = self._write_through(now)
        for offset, word in enumerate(values):
            a = address + offset
            self.regs[a] = word
            w = self._words[a]
            if w.reg.d.eeprom and write_through:
                self.eeprom[a] = word
                self.eeprom_writes += 1
            if (w.reg, w.index) not in touched:
                touched.append((w.reg, w.index))
        try:
            for reg, index in touched:
                self._act(reg, index, now, before)
        except SlaveException:
            self.regs = before
            raise
        if self.description.twin.on_input:
            self._functions_changed(now)

    def _write_through(self, now: float) -> bool:
        """True while a write to an ``eeprom`` register is stored."""
        d = self.description
        if d.twin.eeprom_write_through is not None:
            return bool(self._eval(d.twin.eeprom_write_through, now))
        wt = d.eeprom.write_through
        return wt is not None and self._raw(d.regs[wt.reg], None) == wt.on

    def _check_whole(self, address: int, count: int) -> None:
        """``[link] refusals.split``: a request that starts or ends inside a 32-bit value
        (two registers side by side) is refused, as a drive that keeps its values whole
        refuses it (the JVL MIS: "a 32-bit register must be read or written as two
        consecutive 16-bit registers")."""
        code = self.description.link.refusals.split
        if code is None:
            return
        span = range(address, address + count)
        for a in (address, address + count - 1):  # only the ends can split a value
            pair = self._pairs.get(a)
            if pair is None:
                continue
            r = pair[0].at(pair[1])
            if r.low_address is None and (r.address not in span or r.address + 1 not in span):
                raise SlaveException(code)

    def write_register(self, address: int, word: int, now: float) -> None:
        """One word (FC06): as a write of one register."""
        self.write_registers(address, [word], now)


def _computed(reg: Reg) -> bool:
    return reg.d.means is not None or any(
        b.means is not None or b.twin is not None for b in reg.d.bits.values())


def _clamp(reg: Reg, value: int) -> int:
    r = reg.register
    bits = 16 * r.words
    lo = -(1 << (bits - 1)) if r.signed else 0
    hi = (1 << (bits - 1)) - 1 if r.signed else (1 << bits) - 1
    return max(lo, min(hi, value))
