"""``[registers]``: each register's address, width, sign, unit, range, access and
meaning (``TWIN_MEANINGS``), its bits, and ``Reg``, a register ready to use (its codec
register, a table's entries, the addresses it occupies).
"""

from __future__ import annotations

import re
from collections.abc import Iterator
from dataclasses import dataclass
from functools import cached_property
from typing import Annotated, Any, Literal

from pydantic import BeforeValidator, Field, field_validator, model_validator

from drivebus.drives.description.fields import E, Scale, Source, Unit, Word, _Model
from drivebus.drives.registers import Access, Register, WordOrder
from drivebus.drives.units import UnitCodec
from drivebus.errors import LimitViolation

TWIN_MEANINGS = {
    # what a status bit or register shows, in the twin's terms (docs say each)
    "enabled": "the motor is energised",
    "disabled": "the motor is released",
    "moving": "the motor turns (or a motion is planned)",
    "at_rest": "the motor stands still",
    "in_position": "at rest on the target, no alarm",
    "homed": "a homing completed since power-up",
    "homing": "a homing runs",
    "homing_error": "the last homing failed (the drive's homing error flag)",
    "alarm": "an alarm is latched",
    "no_alarm": "no alarm is latched",
    "limit_positive": "the positive limit switch is active",
    "limit_negative": "the negative limit switch is active",
    "home_switch": "the home switch is active",
    "at_speed": "a speed run reached its speed",
    "ready": "powered and ready (always set)",
    "reached": "a position move or a homing ran to its end (a stop or a new start clears it)",
    "address": "the slave address it answers at",
    "direction": "the direction of the last motion (0 positive, 1 negative)",
    "jogging": "a speed run (jog) is under way",
    "position": "the position counter (pulses)",
    "velocity": "the present speed",
    "command_velocity": "the speed of the running motion",
    "alarm_code": "the latched alarm's code (0: none)",
    "motion": "the kind of motion last started (values: position, speed, homing, ...)",
    "constant": "a fixed value: the register's default (a model code, a version)",
    "inputs": "the input terminals (see [inputs])",
    "outputs": "the output terminals (see [outputs])",
}
"""What a register or bit can mean to the simulated twin."""


def _known_meaning(v: str | None) -> str | None:
    """A ``means`` value, checked against ``TWIN_MEANINGS``."""
    if v is not None and v not in TWIN_MEANINGS:
        raise ValueError(f"unknown meaning {v!r} (known: {', '.join(TWIN_MEANINGS)})")
    return v


class BitDef(_Model):
    """One bit or field of a register."""

    bit: int = Field(ge=0, le=31)
    width: int = Field(1, ge=1, le=32)
    means: str | None = None
    twin: E | None = Field(None, description="twin: the bit's value as an expression over "
                           "the twin's state (where no `means` fits)")
    doc: str = ""
    source: Source | None = None

    _means = field_validator("means")(_known_meaning)

    @property
    def mask(self) -> int:
        """The bits it covers."""
        return ((1 << self.width) - 1) << self.bit


def _bit(v: Any) -> Any:
    return {"bit": v} if isinstance(v, int) and not isinstance(v, bool) else v


class RegisterDef(_Model):
    """One entry of ``[registers]``: a register (or a table of them, with ``count``)."""

    address: Word
    name: str = ""
    words: Literal[1, 2] | None = Field(None, description="1 or 2 registers (default: "
                                        "[link] words, 1 for a coil or discrete input)")
    signed: bool = False
    order: Literal["high_first", "low_first"] | None = None
    low_address: Word | None = None
    offset: int = Field(0, ge=0, le=120, description="object-addressed map: the words of "
                        "the object before it (a sub-index behind the object's address)")
    unit: Unit = ""
    scale: Scale = 1.0
    ramp: str | float | None = None
    table: list[int] = []
    values: dict[str, int] = {}
    min: int | None = None
    max: int | None = None
    default: int = 0
    defaults: list[int] = Field([], description="a table's defaults, entry by entry")
    access: Literal["R", "W", "RW"] = "RW"
    input: bool = Field(False, description="an input register (read with FC04, read-only)")
    coil: bool = Field(False, description="a coil (read with FC01, written with FC05: 0/1)")
    discrete: bool = Field(False, description="a discrete input (read with FC02, read-only: "
                           "0/1)")
    eeprom: bool = False
    volatile: bool = False
    parameter: bool | str | None = Field(
        None, description="a documented setting `drivebus params` backs up (default: RW, "
        "not volatile, no meaning, not the write-through switch); a string is its key in a "
        "parameter file (a table's with {i}, the entry's index, or {name}, its name)")
    comms: bool = Field(False, description="sets the drive's address or line settings")
    means: str | None = None
    bits: dict[str, Annotated[BitDef, BeforeValidator(_bit)]] = {}
    count: int = Field(1, ge=1, le=4096)
    stride: int = Field(1, ge=1, le=4096)
    first: int = Field(0, ge=0, description="index of the table's first entry")
    names: list[str] = Field([], description="a table's entries by name (TABLE['X0'])")
    object: str | None = Field(None, description="CiA 402 object, '6040' or '607A:00'")
    valid: E | None = Field(None, description="twin: a condition on the raw `value` written "
                            "(beyond the range); a write that fails it is refused with "
                            "refusals.value")
    doc: str = ""
    source: Source | None = Field(None, description="where it comes from: 'manual: "
                                  "section, page', 'code: ...' or 'inferred: why'")

    _means = field_validator("means")(_known_meaning)

    def _check_parameter_key(self, key: str) -> None:
        fields = set(re.findall(r"{(\w*)(?::(?:lower|upper))?}", key))
        if self.count > 1 and not fields & {"i", "name"}:
            raise ValueError(f"parameter {key!r}: a table's key needs {{i}} or {{name}} "
                             "(each entry has its own key)")
        if fields - ({"i", "name"} if self.count > 1 else set()):
            raise ValueError(f"parameter {key!r}: only a table's key takes {{i}} or {{name}}")
        if "name" in fields and not self.names:
            raise ValueError(f"parameter {key!r}: {{name}} needs the table's names")
        if not re.fullmatch(r"[A-Za-z_{][\w{}:]*", key):
            raise ValueError(f"parameter {key!r}: a key is a name (letters, digits, _)")

    @model_validator(mode="after")
    def _check(self) -> RegisterDef:
        if self.low_address is not None and self.words == 1:
            raise ValueError("low_address is for a 32-bit register (words = 2)")
        if self.min is not None and self.max is not None and self.min > self.max:
            raise ValueError(f"min {self.min} is above max {self.max}")
        if self.table and self.values:
            raise ValueError("give a table or named values, not both")
        if (self.table or self.values) and self.scale != 1.0:
            raise ValueError("scale does not apply to a table or named values (the table "
                             "gives each raw value's meaning)")
        if self.input and self.access != "R":
            raise ValueError("an input register is read-only: access = \"R\"")
        if sum((self.input, self.coil, self.discrete)) > 1:
            raise ValueError("a register is one of input, coil or discrete (address spaces)")
        if (self.coil or self.discrete) and (self.words == 2 or self.unit or self.bits or
                                             self.signed):
            raise ValueError("a coil or discrete input is one bit (0/1): no words, signed, "
                             "unit or bits")
        if self.discrete and self.access != "R":
            raise ValueError("a discrete input is read-only: access = \"R\"")
        if self.names and len(self.names) != self.count:
            raise ValueError(f"names: {len(self.names)} names for {self.count} entries")
        if self.defaults and len(self.defaults) != self.count:
            raise ValueError(f"defaults: {len(self.defaults)} values for {self.count} entries")
        if isinstance(self.parameter, str):
            self._check_parameter_key(self.parameter)
        bits = 16 * (self.words or 2)  # the link's width is known later: checked again
        for name, b in self.bits.items():
            if b.bit + b.width > bits:
                raise ValueError(f"bit {name} ({b.bit}, width {b.width}) is beyond the "
                                 f"register's {bits} bits")
        return self


@dataclass(frozen=True)
class Reg:
    """A register of a description, ready to use: its key, definition, codec and unit."""

    key: str
    d: RegisterDef
    codec: UnitCodec
    order: WordOrder
    objects: bool = False
    """In an object-addressed map (``[link] map = "objects"``)."""

    @property
    def name(self) -> str:
        """Its display name."""
        return self.d.name or self.key.replace("_", " ")

    @property
    def array(self) -> bool:
        """True for a table of registers (``count`` > 1)."""
        return self.d.count > 1

    @property
    def indices(self) -> range:
        """The indices of a table's entries."""
        return range(self.d.first, self.d.first + self.d.count)

    def at(self, index: int | str | None = None) -> Register:
        """The codec register (of entry ``index`` of a table, a number or one of its
        ``names``); ``LimitViolation`` naming the table and its indices if it is not one."""
        d = self.d
        if index is None and d.count <= 1:  # a single register (most calls)
            return self.register
        if isinstance(index, str) and self.array:
            if index not in d.names:
                shown = ", ".join(d.names) or f"{d.first}..{d.first + d.count - 1}"
                raise LimitViolation(f"{self.name}: no entry {index!r} (it has {shown})")
            index = d.first + d.names.index(index)
        if self.array:
            entry = self._entries.get(index) if isinstance(index, int) and \
                not isinstance(index, bool) else None
            if entry is not None:
                return entry
            if index is None or isinstance(index, bool) or index not in self.indices:
                lo, hi = self.indices.start, self.indices.stop - 1
                raise LimitViolation(f"{self.name}: entry {index!r} is outside {lo}..{hi}")
            n = index - d.first
            name = self._entry_name(index) if "{" in self.name else f"{self.name} {index}"
            entry = self._register(name, d.address + n * d.stride,
                                   None if d.low_address is None else
                                   d.low_address + n * d.stride)
            self._entries[index] = entry
            return entry
        return self.register

    @cached_property
    def _entries(self) -> dict[int, Register]:
        """A table's codec registers made so far, by index (each is made once)."""
        return {}

    @cached_property
    def register(self) -> Register:
        """The codec register of a single register (the first entry of a table)."""
        d = self.d
        return self._register(self._entry_name(d.first), d.address, d.low_address)

    def _entry_name(self, index: int) -> str:
        """The display name of entry ``index``: ``{n}`` its index, ``{name}`` its name."""
        d = self.d
        name = self.name.replace("{n}", str(index))
        if d.names and d.first <= index < d.first + len(d.names):
            name = name.replace("{name}", d.names[index - d.first])
        return name

    def _register(self, name: str, address: int, low: int | None) -> Register:
        d = self.d
        bit = d.coil or d.discrete
        return Register(
            name, address, d.words, signed=d.signed, order=self.order,
            unit=self.codec.raw_unit(),
            minimum=0 if bit and d.min is None else d.min,
            maximum=1 if bit and d.max is None else d.max,
            access=Access(d.access), low_address=low,
            objects=self.objects and self.space == 0, offset=d.offset,
        )

    @property
    def space(self) -> int:
        """Its address space: 0 holding registers, 1 input registers, 2 coils, 3 discrete
        inputs."""
        d = self.d
        return 1 if d.input else 2 if d.coil else 3 if d.discrete else 0

    def addresses(self) -> Iterator[int]:
        """Every address it occupies (every word of every entry); in an object-addressed
        map, ``(address << 8) + word`` for each word of the object it is part of."""
        d = self.d
        if self.objects and self.space == 0:
            for n in range(d.count):
                base = d.address + n * d.stride
                yield from ((base << 8) + d.offset + w for w in range(d.words))
            return
        for n in range(d.count):
            base = d.address + n * d.stride
            yield base
            if d.words == 2:
                yield (d.low_address + n * d.stride) if d.low_address is not None else base + 1

    def default_at(self, index: int | None = None) -> int:
        """The factory value (of entry ``index`` of a table)."""
        d = self.d
        if d.defaults and index is not None:
            return d.defaults[index - d.first]
        return d.default

    def bit_mask(self, name: str) -> int:
        """The mask of bit (field) ``name``."""
        return self.d.bits[name].mask
