"""Drive descriptions: a drive family as data (TOML), validated into typed models.

A description says everything a profile says: who the drive is and how a scan knows it,
its link (baud rates, formats, addresses, function codes, word order, exception texts),
its registers (address, width, sign, unit, range, access, EEPROM wear, volatility), its
units, how its status decodes into ``DriveStatus``, its procedures as ordered steps, its
homing methods, what it cannot do and why, and how it behaves (for its simulated twin).
An engine (``drivebus.drives.engine``) interprets it as a ``DriveProfile``;
``drivebus.sim.described`` builds a twin from the same file.

The format's reference is ``docs/reference/descriptions.md``; the built-in families are
the files in ``drivebus/drives/descriptions/``. ``load_description`` reads and checks one
file: any mistake is one ``ConfigError`` naming the file, the key path and the problem.
"""

from __future__ import annotations

import difflib
import re
import tomllib
from collections.abc import Iterable, Iterator, Mapping
from dataclasses import dataclass
from functools import cached_property
from pathlib import Path
from typing import Annotated, Any, Literal

from pydantic import (
    BaseModel,
    BeforeValidator,
    ConfigDict,
    Field,
    ValidationError,
    ValidationInfo,
    field_validator,
    model_validator,
)

from drivebus.checks import validation_problems
from drivebus.drives.expr import FUNCTIONS, Expr, ExprError, Template
from drivebus.drives.programs import ProgramSupport
from drivebus.drives.registers import Access, Register, WordOrder
from drivebus.drives.units import Kind, UnitCodec, check_unit, parse_scale
from drivebus.errors import ConfigError, LimitViolation
from drivebus.settings import LineSettings

__all__ = [
    "PROCEDURES",
    "SOURCE_KINDS",
    "TWIN_ACTIONS",
    "TWIN_MEANINGS",
    "Description",
    "ExampleDef",
    "Reg",
    "Step",
    "load_description",
    "parse_description",
    "source_kind",
]

FORMAT_VERSION = 1


def _expr(v: Any) -> Any:
    if isinstance(v, Expr):
        return v
    try:
        return Expr.parse(v)
    except ExprError as exc:
        raise ValueError(str(exc)) from None


def _template(v: Any) -> Any:
    if isinstance(v, Template):
        return v
    if not isinstance(v, str):
        raise ValueError(f"expected a text, got {v!r}")
    try:
        return Template.parse(v)
    except ExprError as exc:
        raise ValueError(str(exc)) from None


def _int_keys(v: Any) -> Any:
    """TOML keys are texts: ``"1"`` and ``"0x10"`` become ints."""
    if not isinstance(v, Mapping):
        return v
    out = {}
    for k, val in v.items():
        if isinstance(k, str):
            try:
                k = int(k, 0)
            except ValueError:
                raise ValueError(f"key {k!r} is not a whole number (like 4 or 0x10)") from None
        out[k] = val
    return out


def _scale(v: Any) -> float:
    try:
        return parse_scale(v)
    except ValueError as exc:
        raise ValueError(str(exc)) from None


def _unit(v: Any) -> Any:
    return check_unit(v) if isinstance(v, str) else v


SOURCE_KINDS = ("manual", "code", "inferred")
"""Where an item of a description comes from: the manual (document, section or page),
public code that drives the drive, or inferred (the description's author's reading)."""


def _source(v: Any) -> Any:
    if not isinstance(v, str):
        return v
    kind = re.split(r"[\s:]", v.strip(), maxsplit=1)[0].lower()
    if kind not in SOURCE_KINDS or not v.strip()[len(kind):].strip(" :"):
        raise ValueError(f"source {v!r}: say where it comes from, starting with manual, "
                         f"code or inferred: 'manual: 920-0176 App. 5, p. 110', 'code: "
                         f"github.com/owner/repo driver.py', 'inferred: why'")
    return v.strip()


def source_kind(source: str | None) -> str:
    """``manual``, ``code`` or ``inferred`` of a ``source`` text; ``unnamed`` for None."""
    if not source:
        return "unnamed"
    return re.split(r"[\s:]", source, maxsplit=1)[0].lower()


E = Annotated[Expr, BeforeValidator(_expr)]
Source = Annotated[str, BeforeValidator(_source)]
Unit = Annotated[str, BeforeValidator(_unit)]
T = Annotated[Template, BeforeValidator(_template)]
Scale = Annotated[float, BeforeValidator(_scale)]
IntKeyed = BeforeValidator(_int_keys)
Word = Annotated[int, Field(ge=0, le=0xFFFF)]
_KEY = r"^[A-Za-z_][A-Za-z0-9_]*$"


class _Model(BaseModel):
    model_config = ConfigDict(
        extra="forbid", frozen=True, allow_inf_nan=False, arbitrary_types_allowed=True,
        populate_by_name=True,
    )


# -- identity and link ----------------------------------------------------------------------


class DriveInfo(_Model):
    """``[drive]``: who the drive is and which engine interprets it."""

    family: str = Field(pattern=r"^[A-Za-z0-9][A-Za-z0-9_.+-]{0,31}$")
    vendor: str = ""
    model: str = ""
    description: str = Field("", description="one line, as in drive tables")
    engine: Literal["command", "cia402"] = "command"
    manual: str = Field("", description="where the register tables come from")
    source: Source | None = Field(None, description="where every item without a source of "
                                  "its own comes from ('manual: ...', 'code: ...', "
                                  "'inferred: ...')")
    about: str = Field("", description="what the docs page says about the drive (markdown)")


class Identify(_Model):
    """``[identify]``: how a scan recognises the drive (or why it cannot)."""

    read: list[str] = []
    match: E | None = None
    model: T = Template.parse("")
    firmware: T = Template.parse("")
    raw: dict[str, E] = {}
    cannot: str = ""

    @model_validator(mode="after")
    def _either(self) -> Identify:
        if self.cannot and (self.read or self.match is not None):
            raise ValueError("give either 'cannot' (a reason) or 'read' and 'match'")
        if not self.cannot and (not self.read or self.match is None):
            raise ValueError("needs 'read' (registers) and 'match' (an expression), or "
                             "'cannot' with the reason a scan cannot tell this drive")
        return self


class FormatRule(_Model):
    """A restriction of the formats at some baud rates."""

    baud_rates: list[int] = Field(min_length=1)
    formats: list[str] = Field(min_length=1)
    why: str = ""


class Refusals(_Model):
    """The exception code the drive answers for each kind of refusal (its twin uses them)."""

    function: int = Field(1, ge=1, le=255)
    address: int = Field(2, ge=1, le=255)
    outside: int | None = Field(None, ge=1, le=255, description="an address outside its map")
    access: int = Field(2, ge=1, le=255)
    read_access: int | None = Field(None, ge=1, le=255, description="a read of a write-only "
                                    "register, where it differs from access")
    value: int = Field(3, ge=1, le=255)
    count: int = Field(3, ge=1, le=255)
    crc: int | None = Field(None, ge=1, le=255, description="reply to a bad CRC (else silence)")
    busy: int | None = Field(None, ge=1, le=255, description="a command it cannot carry out now")


class Timing(_Model):
    """Per-drive timing."""

    response_timeout: float | None = Field(None, gt=0, le=10, description="s")
    guard: float = Field(0.0, ge=0, le=1, description="extra silence before its frames, s "
                         "(the bus keeps it, on top of the line's silence)")
    frame_timeout: float | None = Field(None, gt=0, le=1, description="extra silence after "
                                        "its replies, s, for bytes it trails after a frame")


_LINE_KINDS = Literal["serial", "rtu-over-tcp", "tcp"]
_FORMAT = r"^[5-8][NEO][12]$"


class ParameterNumbers(_Model):
    """``[link] parameter_numbers``: how the manual's parameter numbers (``"P5-07"``) give
    register addresses, for a manual that lists parameters by group and number."""

    pattern: str = Field(description="the numbers' form, its parts in braces: 'P{group}-{number}'")
    address: E = Field(description="the address of a number, an expression of its parts: "
                       "'group * 0x100 + number * 2'")

    @model_validator(mode="after")
    def _check(self) -> ParameterNumbers:
        parts = re.findall(r"{([A-Za-z_]\w*)}", self.pattern)
        if not parts:
            raise ValueError(f"pattern {self.pattern!r}: name its numbered parts in braces, "
                             "'P{group}-{number}'")
        unknown = self.address.names - set(parts) - set(FUNCTIONS)
        if unknown:
            raise ValueError(f"address {self.address.source!r}: {', '.join(sorted(unknown))} "
                             f"is not a part of the pattern {self.pattern!r}")
        return self

    def regex(self) -> re.Pattern[str]:
        """The pattern as a regular expression (each part a decimal number)."""
        out = ""
        for literal, part in re.findall(r"([^{]*)(?:{([A-Za-z_]\w*)})?", self.pattern):
            out += re.escape(literal) + (f"(?P<{part}>[0-9]+)" if part else "")
        return re.compile(out, re.IGNORECASE)

    def resolve(self, number: str) -> int:
        """The register address of the manual's parameter ``number``; ``ValueError`` if it
        is not of the pattern's form or its address is not a register's."""
        m = self.regex().fullmatch(number.strip())
        if m is None:
            raise ValueError(f"{number!r} is not a parameter number of the form "
                             f"{self.pattern!r} (link.parameter_numbers)")
        address = self.address({k: int(v) for k, v in m.groupdict().items()})
        if not isinstance(address, int) or not 0 <= address <= 0xFFFF:
            raise ValueError(f"{number!r}: link.parameter_numbers gives {address!r}, not a "
                             "register address (0..65535)")
        return address


class Link(_Model):
    """``[link]``: how the drive is reached and what it accepts."""

    protocol: Literal["rtu", "tcp"] = "rtu"
    kinds: list[_LINE_KINDS] | None = None
    addresses: tuple[int, int] | list[int] = Field(
        (1, 247), description="'LO..HI' (a range), or a list of the addresses it can have "
        "([255]: only 255)")
    baud_rates: list[Annotated[int, Field(gt=0)]] = []
    formats: list[Annotated[str, Field(pattern=_FORMAT)]] = []
    format_rules: list[FormatRule] = []
    factory: str | None = Field(None, description="line settings out of the box: '9600 8N1'")
    format_register: str | None = Field(None, description="the register that sets its line "
                                        "format (its named values: '8N1' = 0, ...)")
    baud_register: str | None = Field(None, description="the register that sets its baud "
                                      "rate (its named values: '9600' = 0, ...)")
    address_register: str | None = Field(None, description="the register that sets its "
                                         "address (`drivebus commission`)")
    comms_note: str = Field("", description="how it takes a new address or line settings "
                            "(switches, a save, a power cycle)")
    register_addresses: tuple[int, int] | None = Field(
        None, description="the addresses address_register can give ('32..127'); the others "
        "are set another way (comms_note)")
    functions: list[Literal[1, 2, 3, 4, 5, 6, 16]] = [3, 6, 16]
    max_read: int = Field(125, ge=1, le=125)
    max_write: int = Field(123, ge=1, le=123)
    max_hole: int = Field(0, ge=0, le=124, description="largest gap a coalesced read spans")
    word_order: Literal["high_first", "low_first"] = "high_first"
    register_base: Literal[0, 1, 40001] = Field(
        0, description="the number the manual gives the first register: 0 (PDU addresses, "
        "as on the wire), 1 (1-based) or 40001 (4xxxx numbering; input registers 3xxxx); "
        "[registers] addresses are then the manual's numbers")
    map: Literal["words", "objects"] = Field(
        "words", description="words: a flat array of 16-bit registers (a 32-bit value "
        "takes its address and the next); objects: an address per object, each read and "
        "written with its own address and width (a sub-index at an offset behind it, or at "
        "an address of its own), never merged with the next address")
    parameter_numbers: ParameterNumbers | None = Field(
        None, description="registers' addresses from the manual's parameter numbers: "
        "address = \"P5-07\"")
    exceptions: Annotated[dict[int, str], IntKeyed] = {}
    refusals: Refusals = Refusals()
    timing: Timing = Timing()

    @field_validator("addresses", "register_addresses", mode="before")
    @classmethod
    def _addresses(cls, v: Any, info: ValidationInfo) -> Any:
        if isinstance(v, str):
            lo, sep, hi = v.partition("..")
            try:
                return (int(lo, 0), int(hi, 0)) if sep else [int(v, 0)]
            except ValueError:
                raise ValueError(f"{v!r}: expected 'LO..HI' like '1..31'") from None
        if isinstance(v, list | tuple) and info.field_name == "addresses":
            return list(v)  # a list: the addresses themselves, not a range
        return v

    @model_validator(mode="after")
    def _check(self) -> Link:
        if isinstance(self.addresses, tuple):
            lo, hi = self.addresses
            if lo > hi:
                raise ValueError(f"addresses {lo}..{hi}: the first is above the last")
            given = [lo, hi]
        else:
            if not self.addresses:
                raise ValueError("addresses: an empty list (give 'LO..HI' or the addresses)")
            given = self.addresses
        first, last = (0, 255) if self.protocol == "tcp" else (1, 247)
        bad = [a for a in given if not first <= a <= last]
        if bad:
            what = "a Modbus TCP unit id is 0..255" if self.protocol == "tcp" else \
                "an RTU address is 1..247 (0 is broadcast); a Modbus TCP unit id is 0..255 " \
                "(protocol = \"tcp\")"
            raise ValueError(f"addresses: {bad[0]} is outside {first}..{last}: {what}")
        if self.factory is not None:
            LineSettings.parse(self.factory)
        return self

    @property
    def address_set(self) -> range | tuple[int, ...]:
        """The addresses (unit ids) the drive can have."""
        if isinstance(self.addresses, tuple):
            return range(self.addresses[0], self.addresses[1] + 1)
        return tuple(sorted(set(self.addresses)))

    @property
    def line_kinds(self) -> frozenset[str]:
        """The kinds of line that reach it."""
        if self.kinds is not None:
            return frozenset(self.kinds)
        if self.protocol == "tcp":
            return frozenset({"tcp"})  # MBAP only: no RTU frames over its socket
        return frozenset({"serial", "rtu-over-tcp", "tcp"})  # tcp: through a gateway

    @property
    def order(self) -> WordOrder:
        """The default 32-bit word order."""
        return WordOrder(self.word_order)


# -- registers ----------------------------------------------------------------------------


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
    words: Literal[1, 2] = 1
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
        if self.low_address is not None and self.words != 2:
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
        if (self.coil or self.discrete) and (self.words != 1 or self.unit or self.bits or
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
        bits = 16 * self.words
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


# -- options, units, status ------------------------------------------------------------------


class OptionDef(_Model):
    """One of the drive's ``drive_options``."""

    type: Literal["int", "float", "bool", "str", "choice", "map", "list"] = "int"
    min: float | None = None
    max: float | None = None
    choices: list[str] = []
    keys: list[str] = Field([], description="map: the keys allowed")
    max_items: int | None = Field(None, ge=1, description="list: the most entries (integers "
                                  "within min..max, each once)")
    default: Any = None
    doc: str = ""

    @model_validator(mode="after")
    def _check(self) -> OptionDef:
        if self.type == "choice" and not self.choices:
            raise ValueError("a choice needs 'choices'")
        if self.type == "map" and not (self.keys and self.choices):
            raise ValueError("a map needs 'keys' and 'choices' (its values)")
        return self


class OptionCheck(_Model):
    """A condition the options together must meet (two options naming one terminal)."""

    check: E
    message: T


class PulsesPerRev(_Model):
    """How many pulses make a revolution, and what the axis may set."""

    default: int = Field(gt=0)
    reg: str | None = Field(None, alias="register", description="the register that sets it "
                            "(its range or table gives the allowed values)")
    allowed: list[int] = Field([], description="the values allowed (else any, or the "
                                               "register's)")
    range: tuple[int, int] | None = None


class Units(_Model):
    """``[units]``."""

    pulses_per_rev: PulsesPerRev


class PollDef(_Model):
    """A conditional read of a status poll."""

    read: list[str | list[str]]
    when: E


class CompletionDef(_Model):
    """``[status.completion]``: a short read that tells whether a motion has ended (a
    buffered move of a motion program starts on it)."""

    read: list[str | list[str]] = Field(min_length=1)
    moving: E | None = None
    in_position: E | None = None
    alarm: E | None = None
    limit_positive: E | None = None
    limit_negative: E | None = None
    """Each field: an expression on what ``read`` reads; not given, ``[status]``'s own (an
    alarm or limit field the read cannot decode is then False: the status polls judge it)."""


class StatusDef(_Model):
    """``[status]``: the poll and how it decodes into ``DriveStatus``."""

    poll: list[str | list[str]] = []
    extra: list[PollDef] = []
    enabled: E | None = None
    moving: E | None = None
    in_position: E | None = None
    homed: E | None = None
    homing: E | None = None
    homing_error: E | None = Field(None, description="the drive reports that a homing "
                                   "failed: the homing under way ends at once")
    alarm: E | None = None
    alarm_code: E | None = None
    limit_positive: E | None = None
    limit_negative: E | None = None
    position: E | None = None
    velocity: E | None = None
    raw: dict[str, E] = {}
    track: dict[str, E] = Field({}, description="state variables updated after each poll")
    learn_first: bool = Field(False, description="run learn before the first poll (else "
                              "decoding uses the registers' defaults until setup or learn)")
    completion: CompletionDef | None = None


class IoDef(_Model):
    """``[inputs]`` / ``[outputs]``: which terminal carries which signal."""

    state: str
    invert: str | None = None
    functions: str | None = None
    codes: dict[str, int] = {}
    bits: dict[str, int] = Field({}, description="fixed wiring: signal -> bit number")
    polarity: str | None = Field(None, description="a register whose bits invert the sense "
                                 "of the terminals before the drive acts on them (`state` "
                                 "shows the levels after it; the twin honours it)")
    names: list[Annotated[str, Field(min_length=1)]] = Field(
        [], description="the terminals by the manual's names, in the order of the state "
        "register's bits (digital I/O by name)")
    function_mask: int = Field(0xFFFF, ge=1, le=0xFFFF, description="the bits of a "
                               "`functions` entry that hold the function code")
    polarity_bit: int | None = Field(None, ge=1, le=0xFFFF, description="a bit of each "
                                     "`functions` entry that inverts its terminal before the "
                                     "drive acts on it (`state` shows the terminals as wired)")
    function_names: Annotated[dict[int, str], IntKeyed] = Field(
        {}, description="the manual's name of each function code (what `io_points` says a "
        "terminal is set to do)")
    settable: int | None = Field(None, description="outputs: the function code under which "
                                 "Modbus switches the output (set_output)")
    values: str | None = Field(None, description="outputs: the register whose bit n an output "
                               "n follows while its function is `settable` (the twin)")
    first: int = Field(0, ge=0, le=1, description="the number the twin's set_input gives the "
                       "first terminal (1 where the manual counts IN1, IN2, ...)")


class AlarmsDef(_Model):
    """``[alarms]``: the alarm code register and the texts of its codes."""

    reg: str = Field(alias="register")
    kind: Literal["code", "flags"] = "code"
    texts: Annotated[dict[int, str], IntKeyed] = {}
    unknown: T = Template.parse("alarm code {code}")
    clears: Annotated[dict[int, Literal["command", "power_cycle", "supply"]], IntKeyed] = {}


class WriteThroughDef(_Model):
    """A switch that makes every Modbus write an EEPROM write while it holds ``on``."""

    reg: str = Field(alias="register")
    on: int
    off: int


class EepromDef(_Model):
    """``[eeprom]``: how the drive stores its settings."""

    write_through: WriteThroughDef | None = None
    saves_by_write_through: bool = Field(
        False, description="no save command: a value is stored only when written with the "
        "write-through switch on")


class SignalDef(_Model):
    """A further value read in its own poll group (temperature, bus voltage, ...)."""

    reg: str = Field(alias="register")
    every: float = Field(1.0, gt=0, le=3600, description="s")
    doc: str = ""


class ProgramsDef(_Model):
    """``[programs]``: what the drive offers motion programs (``ProgramSupport``), each
    the manual's reason, or "" where it cannot."""

    preload: str = Field("", description="why the next move's values may be written while "
                         "a move runs (the drive latches them at the start)")
    preload_braking: str = Field("", description="why they may be written in the running "
                                 "move's braking, if no gentler")
    retarget: str = Field("", description="how a running move takes a new target (needs "
                          "procedures.retarget_absolute)")
    no_retarget: str = ProgramSupport.no_retarget
    jog_speed: str = Field("", description="how a running speed run takes a new speed")
    table_rows: int = Field(0, ge=0, le=1024, description="rows of its position table "
                            "(`prepare_table`/`start_table`)")

    def support(self) -> ProgramSupport:
        """The ``ProgramSupport`` a profile declares."""
        return ProgramSupport(**self.model_dump(exclude={"table_rows"}))


class HomingMethod(BaseModel):
    """One homing method: its code for the drive and the behaviour its twin plays."""

    model_config = ConfigDict(extra="allow", frozen=True)

    code: int | None = None
    cia402: int | None = Field(None, description="the equivalent CiA 402 method (twin)")
    behaviour: Literal["search", "set", "move_to_offset", "reference_edge", "hard_stop"] | \
        None = None
    reference: Literal["home_switch", "limit_positive", "limit_negative"] | None = Field(
        None, description="reference_edge: the signal whose rising edge is the origin")
    direction: Literal[-1, 1] | None = Field(None, description="reference_edge, hard_stop: "
                                             "the search direction")
    doc: str = ""
    source: Source | None = None

    @model_validator(mode="after")
    def _reference(self) -> HomingMethod:
        if self.behaviour == "reference_edge" and (self.reference is None or
                                                   self.direction is None):
            raise ValueError("behaviour reference_edge needs 'reference' and 'direction'")
        if self.behaviour == "hard_stop" and self.direction is None:
            raise ValueError("behaviour hard_stop needs 'direction'")
        return self

    @property
    def extras(self) -> dict[str, Any]:
        """The method's further values (usable as ``home.NAME`` in expressions)."""
        return dict(self.model_extra or {})


class HomingDef(_Model):
    """``[homing]``: the drive's homing methods, the first is the default."""

    methods: dict[str, HomingMethod] = Field(min_length=1)


# -- procedures ---------------------------------------------------------------------------


class WriteItem(_Model):
    """A value to write, with constraints beyond the register's range."""

    value: E
    nonzero: bool = Field(False, description="the raw value must not be 0 (a move's speed)")
    raw: bool = Field(False, description="the value is what the register holds (no unit "
                      "conversion; still range-checked): a fastest ramp code, a bit pattern")


def _item(v: Any) -> Any:
    return v if isinstance(v, Mapping | WriteItem) else {"value": v}


Priorities = Literal["emergency", "command", "config", "poll"]
_ACTIONS = ("write", "read", "modify", "call", "check", "wait", "set", "fail", "return_")


class Step(_Model):
    """One step of a procedure (exactly one action key, plus modifiers)."""

    model_config = ConfigDict(populate_by_name=True)

    write: dict[str, Annotated[WriteItem, BeforeValidator(_item)]] | None = None
    read: list[str | list[str]] | None = None
    modify: str | None = None
    call: str | None = None
    check: E | None = None
    wait: E | None = None
    set: dict[str, E] | None = None
    fail: T | None = None
    return_: E | None = Field(None, alias="return")
    # modifiers
    when: E | None = None
    block: E | None = None
    single: bool = Field(False, description="32-bit values as FC06 word by word")
    idempotent: bool = True
    priority: Priorities | None = None
    start: bool = Field(False, description="where a prepared move starts")
    volatile: bool = False
    end: bool = Field(False, description="the procedure ends after this step")
    args: dict[str, E] = {}
    bits_set: E | None = Field(None, alias="set_bits")
    bits_clear: E | None = Field(None, alias="clear_bits")
    bits_toggle: E | None = Field(None, alias="toggle_bits")
    pulse: bool = Field(False, description="modify: toggle, then toggle back")
    if_changed: bool = Field(False, description="write: only the registers whose value "
                             "differs from what the drive holds (read in this run, else "
                             "read now)")
    each: str | None = Field(None, pattern=r"^\s*[A-Za-z_][A-Za-z0-9_]*\s+in\s+.+$",
                             description="write: 'NAME in EXPRESSION', the step's writes "
                             "once per value of a list (per key of a map, in its order; "
                             "in one block with `block`)")
    timeout: E = Expr.parse(5.0)
    every: float = Field(0.005, gt=0, le=10)
    error: Literal["alarm", "state", "motion", "limit"] = "state"
    message: T | None = None

    @model_validator(mode="after")
    def _one_action(self) -> Step:
        given = [a.rstrip("_") for a in _ACTIONS if getattr(self, a) is not None]
        if self.wait is not None and "read" in given:
            given.remove("read")  # a wait's `read`: what each of its polls reads
        if len(given) != 1:
            keys = ", ".join(a.rstrip("_") for a in _ACTIONS)
            got = f"got {', '.join(given)}" if given else "got none"
            raise ValueError(f"a step has exactly one of {keys} ({got})")
        if self.modify is not None and self.bits_set is None and self.bits_clear is None \
                and self.bits_toggle is None:
            raise ValueError("a modify step needs set_bits, clear_bits or toggle_bits")
        if self.each is not None:
            if self.write is None:
                raise ValueError("'each' repeats a write step only")
            Expr.parse(self.each.split(" in ", 1)[1])
        return self

    @property
    def action(self) -> str:
        """The step's action key."""
        if self.wait is not None:
            return "wait"
        return next(a.rstrip("_") for a in _ACTIONS if getattr(self, a) is not None)


class Param(_Model):
    """A parameter of a procedure of the drive's own."""

    name: str = Field(pattern=_KEY)
    default: Any = None
    doc: str = ""


def _param(v: Any) -> Any:
    return {"name": v} if isinstance(v, str) else v


class Procedure(_Model):
    """One procedure: its steps, or why the drive cannot do it."""

    steps: list[Step] = []
    params: list[Annotated[Param, BeforeValidator(_param)]] = []
    what: T | None = None
    unsupported: str | None = None
    supported: E | None = Field(None, description="a condition on the options")
    why: str = ""
    priority: Priorities | None = None
    takes: list[str] | None = Field(None, description="the parameters it honours (default: "
                                    "those its steps use); a stop that takes no decel refuses "
                                    "one before anything is sent")
    doc: str = ""
    source: Source | None = None

    def uses(self) -> set[str]:
        """The names its steps' expressions use (what it honours of its parameters)."""
        names: set[str] = set()
        for step in self.steps:
            for value in step.__dict__.values():
                if isinstance(value, Expr | Template):
                    names |= value.names
            for item in (step.write or {}).values():
                names |= item.value.names
            for e in (*(step.set or {}).values(), *step.args.values()):
                names |= e.names
            if step.each is not None:
                names |= Expr.parse(step.each.split(" in ", 1)[1]).names
        return names

    def honours(self, param: str) -> bool:
        """Whether it takes parameter ``param`` (``takes``, else its steps use it)."""
        return param in self.takes if self.takes is not None else param in self.uses()

    @model_validator(mode="after")
    def _check(self) -> Procedure:
        if self.unsupported is not None and self.steps:
            raise ValueError("an unsupported procedure has no steps")
        if self.unsupported is None and not self.steps:
            raise ValueError("needs steps (or 'unsupported' with the reason)")
        return self


PROCEDURES: dict[str, tuple[str, tuple[str, ...]]] = {
    "learn": ("learn what decoding needs (reads only)", ()),
    "setup": ("set the drive up", ()),
    "enable": ("enable the motor", ()),
    "disable": ("disable the motor", ()),
    "move_absolute": ("make an absolute move", ("target", "speed", "accel", "decel")),
    "move_relative": ("make a relative move", ("distance", "speed", "accel", "decel")),
    "speed_run": ("run at a set speed", ("speed", "accel", "decel")),
    "stop": ("stop with deceleration", ("decel",)),
    "emergency_stop": ("make an emergency stop", ()),
    "home": ("home", ("method", "speed", "creep", "accel", "offset")),
    "clear_alarm": ("clear an alarm", ()),
    "zero_position": ("set its position to zero", ()),
    "save_parameters": ("save parameters", ()),
    "retarget_absolute": ("take a new target while it moves",
                          ("target", "speed", "accel", "decel")),
}
"""The common procedures: what a NotSupported error says, and the names they pass."""

EXTRA_PROCEDURES = ("set_output", "prepare_table", "start_table")
"""Procedures the engine runs besides the common ones (I/O and motion programs)."""


# -- the twin -----------------------------------------------------------------------------


TWIN_ACTIONS = {
    "move_absolute": ("target", "speed", "accel", "decel"),
    "move_relative": ("distance", "speed", "accel", "decel"),
    "run": ("speed", "accel", "decel"),
    "set_speed": ("speed",),
    "stop": ("decel",),
    "emergency_stop": ("decel",),
    "home": ("method", "speed", "creep", "accel", "offset"),
    "enable": (),
    "disable": (),
    "clear_alarm": (),
    "zero_position": (),
    "set_position": ("position",),
    "save": (),
    "factory_reset": (),
    "run_table": ("rows", "target", "distance", "speed", "accel", "decel", "wait", "repeat"),
    "refuse": (),
    "none": (),
}
"""What a twin does on a trigger, and the parameters each action takes."""


class Trigger(_Model):
    """What the drive does when a register is written."""

    reg: str = Field(alias="register")
    when: E | None = None
    do: Literal[tuple(TWIN_ACTIONS)]  # type: ignore[valid-type]
    target: E | None = None
    distance: E | None = None
    speed: E | None = None
    accel: E | None = None
    decel: E | None = None
    creep: E | None = None
    method: E | None = None
    offset: E | None = None
    position: E | None = None
    rows: E | None = Field(None, description="run_table: how many rows run (`row` counts "
                           "from 1 in the row expressions)")
    wait: E | None = Field(None, description="run_table: s to wait after a row's move")
    repeat: E | None = Field(None, description="run_table: run the rows again and again "
                             "(the last row's wait kept) until stopped")
    motion: str | None = Field(None, description="the motion kind it starts (mode register)")
    more: bool = Field(False, description="go on to the next triggers of the register")
    refuse: bool = Field(False, description="refuse with refusals.busy when it cannot start")
    set: dict[str, E] = Field({}, description="registers the drive sets when the trigger "
                              "fires, raw values (an acknowledge, a command register it "
                              "clears)")
    ends: dict[str, E] = Field({}, description="registers the drive sets once the motion "
                               "the trigger started is over (done, failed or stopped), raw "
                               "values (a command register that reads back while it runs)")


class InputTrigger(Trigger):
    """What the drive does when an input function turns active (or inactive)."""

    reg: str = Field("", alias="register")
    input: str = Field(description="the input function ([inputs] codes)")
    edge: Literal["rise", "fall"] = "rise"


class LimitsDef(_Model):
    """How the drive reacts at a limit switch."""

    stop: E = Expr.parse("'decelerate'")
    decel: E | None = None
    block_start: bool = True


class TwinHomingDef(_Model):
    """``[twin.homing]``: how a ``reference_edge`` homing leaves its reference and what a
    limit switch in the search does."""

    backoff: Literal["speed", "creep"] = Field(
        "speed", description="the speed of the leg that backs off the reference")
    backoff_stop: Literal["brake", "at_once"] = Field(
        "brake", description="where the back-off leaves the reference: brake at the homing "
        "acceleration, or stop at once on the edge")
    reverse_at_limit: E = Field(Expr.parse(True), description="a limit switch met ahead in "
                                "the search reverses it (else the homing fails there)")
    after_reversal: Literal["other_edge", "same_edge"] = Field(
        "other_edge", description="after a reversal: search the reference's other edge, or "
        "pass through the reference and creep back to the edge the search looked for")
    offset: E | None = Field(None, description="what the offset does, chosen when the homing "
                             "starts: an expression giving 'origin', 'move' or 'travel' "
                             "(default: [twin] home_offset)")
    offset_speed: Literal["creep", "speed"] = Field(
        "creep", description="the speed of an offset travelled after the origin")


class TwinDef(_Model):
    """``[twin]``: how the drive behaves, for its simulated twin."""

    on_write: list[Trigger] = []
    on_input: list[InputTrigger] = Field(
        [], description="actions on an input function's edge (a terminal, its polarity bit "
        "or its function changed)")
    direct: list[Literal["home_switch", "limit_positive", "limit_negative"]] = Field(
        [], description="switches the drive sees without an input terminal")
    options: list[str] = Field([], description="registers a twin option sets before "
                               "power-up (a choice the machine's builder made: wiring, mode)")
    stall_time: E = Field(Expr.parse(0.0), description="s: how long the motor stalls on a "
                          "hard stop before the drive takes it as the origin (hard_stop)")
    starts: E = Expr.parse("enabled and not alarm")
    limits: LimitsDef = LimitsDef()
    eeprom_write_through: E | None = Field(
        None, description="when a write to an `eeprom` register is stored (default: the "
        "[eeprom] write-through switch holds its `on` value)")
    enabled: E = Expr.parse(True)
    decel: E | None = Field(None, description="an alarm or a disable: None = at once")
    wiring: dict[Literal["home_switch", "limit_positive", "limit_negative"], str | int] = Field(
        {}, description="the input terminal (a name of [inputs] names, or a bit) each "
        "simulated switch is wired to; the drive acts on it as its function register and "
        "[inputs] polarity say")
    max_pulse_rate: float | None = Field(None, gt=0, description="pulses/s: the fastest "
                                         "the drive's pulse output runs (speeds above are capped)")
    home_offset: Literal["origin", "move", "travel"] = Field(
        "origin", description="origin: the origin edge takes the offset as its position; "
        "move: the counter is 0 at the edge and a compensation move of the offset follows; "
        "travel: the offset is travelled past the edge and the point reached is 0")
    homing: TwinHomingDef = TwinHomingDef()


# -- the CiA 402 engine ---------------------------------------------------------------


class ObjectUnit(_Model):
    """How the registers of one kind of CiA 402 object hold their values."""

    unit: Unit
    scale: Scale = 1.0


class Cia402Def(_Model):
    """``[cia402]``: how a CiA 402 drive maps its objects and runs its state machine."""

    address_rule: E | None = Field(None, description="the address of an object from its "
                                   "`index` and `sub` (for the objects listed in `objects`)")
    objects: list[str] = Field([], description="objects whose registers the rule places")
    words: Literal[2] | None = Field(None, description="2: every object the rule places "
                                     "takes two registers, 16-bit ones too (a drive that "
                                     "stores each parameter in 32 bits); default: by the "
                                     "object's width")
    position: ObjectUnit = ObjectUnit(unit="pulses")
    velocity: ObjectUnit = ObjectUnit(unit="pulses/s")
    acceleration: ObjectUnit = ObjectUnit(unit="pulses/s²")
    emergency_stop: Literal["quick_stop", "halt"] = "quick_stop"
    change_set_immediately: bool = Field(False, description="a new move replaces a running "
                                         "one at once (controlword bit 5)")
    timeout: float = Field(1.0, gt=0, le=30, description="s, for a state change or a "
                           "set-point acknowledge")
    blocks: list[Annotated[list[str], Field(min_length=2)]] = Field(
        [], description="objects the drive takes in one FC16, each list at registers that "
        "follow on ('profile_velocity', 'profile_acceleration'); every other object is "
        "written in a request of its own")

    def block_of(self, name: str) -> int | None:
        """The index of the block of ``blocks`` object ``name`` belongs to (None: none)."""
        for i, block in enumerate(self.blocks):
            if any(object_name(ref) == name for ref in block):
                return i
        return None


def object_name(ref: str) -> str | None:
    """The CiA 402 object ``ref`` names: an object name, or its index (``6040``,
    ``0x6040``, ``6040h``) with an optional sub-index (``6099:01``, ``6099.1``)."""
    from drivebus.drives.cia402 import OBJECTS

    if ref in OBJECTS:
        return ref
    text = ref.strip().lower().removeprefix("0x")
    index_s, _, sub_s = text.replace(".", ":").partition(":")
    index_s = index_s.removesuffix("h")
    try:
        index = int(index_s, 16)
        sub = int(sub_s.removesuffix("h"), 16) if sub_s else 0
    except ValueError:
        return None
    for name, info in OBJECTS.items():
        if info.index == index and info.subindex == sub:
            return name
    return None


# -- the manual's example frames -----------------------------------------------------------


def _frames(v: Any) -> Any:
    return [v] if isinstance(v, str) else v


class ExampleDef(_Model):
    """``[[examples]]``: a frame the manual prints and what it stands for; ``drivebus
    drive check`` verifies that the engine sends exactly those bytes for it and decodes
    the printed reply to the printed values (``drivebus.drives.examples``)."""

    doc: str = Field("", description="what the manual says the frame does")
    source: Source | None = Field(None, description="where the manual prints it")
    request: Annotated[list[str], BeforeValidator(_frames)] = Field(
        min_length=1, description="the request frame(s) as printed: '01 06 00 1D 02 58 D9 8B' "
        "(RTU, CRC included) or an MBAP frame; several: in the order the engine sends them")
    reply: Annotated[list[str], BeforeValidator(_frames)] = Field(
        [], description="the reply frame(s) as printed, for the requests in order")
    write: dict[str, Any] | None = Field(None, description="what the request writes: "
                                         "register = value (physical, as a procedure's)")
    raw: bool = Field(False, description="write: the values are what the registers hold")
    block: bool = Field(False, description="write: in one FC16 (the registers form a block)")
    read: list[str | list[str]] | None = Field(None, description="what the request reads: "
                                               "register keys, or spans [first, last]")
    procedure: str | None = Field(None, description="the procedure the frames stand for")
    args: dict[str, Any] = Field({}, description="procedure: its arguments (drive units)")
    values: dict[str, Any] = Field({}, description="read: what the reply decodes to "
                                   "(physical values)")
    pulses_per_rev: int | None = Field(None, gt=0, description="the pulses per revolution "
                                       "the example assumes (default: the description's)")
    options: dict[str, Any] = Field({}, description="drive_options the example assumes")
    erratum: str = Field("", description="what the manual got wrong in it (a printed CRC, "
                         "an address of another model's map): a wrong CRC is then checked "
                         "as corrected, and an example that stands for nothing the drive "
                         "does is listed, not run")

    listed: str = Field("", description="why the example is listed but not run (a frame "
                        "with a bad CRC on purpose, an address the description leaves out, a "
                        "value the engine refuses before sending)")

    @model_validator(mode="after")
    def _one(self) -> ExampleDef:
        given = [k for k in ("write", "read", "procedure") if getattr(self, k) is not None]
        if not given and (self.erratum or self.listed):
            return self  # printed, but standing for nothing this drive does: said, not run
        if len(given) != 1:
            raise ValueError("an example stands for exactly one of write, read or procedure "
                             f"(got {', '.join(given) or 'none'})")
        if self.values and self.read is None:
            raise ValueError("values are what a read's reply decodes to: give read")
        return self


# -- the whole description ---------------------------------------------------------------


class Description(_Model):
    """A whole description file."""

    format: Literal[1] = 1
    drive: DriveInfo
    identify: Identify | None = None
    link: Link = Link()
    registers: dict[Annotated[str, Field(pattern=_KEY)], RegisterDef] = {}
    constants: dict[Annotated[str, Field(pattern=_KEY)], int] = {}
    state: dict[Annotated[str, Field(pattern=_KEY)], int | float | bool | str | None] = {}
    options: dict[Annotated[str, Field(pattern=_KEY)], OptionDef] = {}
    option_checks: list[OptionCheck] = []
    units: Units
    status: StatusDef = StatusDef()
    inputs: IoDef | None = None
    outputs: IoDef | None = None
    alarms: AlarmsDef | None = None
    homing: HomingDef | None = None
    signals: dict[Annotated[str, Field(pattern=_KEY)], SignalDef] = {}
    eeprom: EepromDef = EepromDef()
    programs: ProgramsDef = ProgramsDef()
    cia402: Cia402Def | None = None
    procedures: dict[Annotated[str, Field(pattern=_KEY)], Procedure] = {}
    twin: TwinDef = TwinDef()
    examples: list[ExampleDef] = []

    def provenance(self) -> dict[str, list[str]]:
        """Where every register, bit, procedure and homing method comes from, by kind
        (``manual``, ``code``, ``inferred``, ``unnamed``): the item's own ``source``, else
        the register's (for its bits), else ``[drive] source``."""
        default = self.drive.source
        out: dict[str, list[str]] = {k: [] for k in (*SOURCE_KINDS, "unnamed")}
        for key, r in self.registers.items():
            out[source_kind(r.source or default)].append(f"registers.{key}")
            for bit, b in r.bits.items():
                out[source_kind(b.source or r.source or default)].append(
                    f"registers.{key}.bits.{bit}")
        for name, p in self.procedures.items():
            out[source_kind(p.source or default)].append(f"procedures.{name}")
        for name, m in (self.homing.methods.items() if self.homing else ()):
            out[source_kind(m.source or default)].append(f"homing.methods.{name}")
        return out

    # -- compiled views ---------------------------------------------------------------------

    @cached_property
    def regs(self) -> dict[str, Reg]:
        """Every register, by key (with those a CiA 402 address rule places)."""
        out = {}
        placed = {k: self._pdu_addresses(d) for k, d in self.registers.items()}
        for key, d in {**placed, **self._generated()}.items():
            codec = UnitCodec.make(d.unit, d.scale, d.ramp, d.table, d.values)
            order = WordOrder(d.order) if d.order else self.link.order
            out[key] = Reg(key, d, codec, order, objects=self.link.map == "objects")
        return out

    def register_base(self, d: RegisterDef) -> int:
        """What ``d``'s numbers count from (``link.register_base``; under 4xxxx numbering,
        input registers 3xxxx, coils 0xxxx, discrete inputs 1xxxx)."""
        base = self.link.register_base
        if base != 40001:
            return base
        return 30001 if d.input else 1 if d.coil else 10001 if d.discrete else base

    def _pdu_addresses(self, d: RegisterDef) -> RegisterDef:
        """``d`` with PDU addresses (its numbers less the register base; a number below
        the base stays as it is and the checks name it)."""
        base = self.register_base(d)
        if not base or d.address < base or (d.low_address is not None and
                                            d.low_address < base):
            return d
        low = None if d.low_address is None else d.low_address - base
        return d.model_copy(update={"address": d.address - base, "low_address": low})

    @cached_property
    def objects(self) -> dict[str, Reg]:
        """The registers of the CiA 402 objects, by object name."""
        out: dict[str, Reg] = {}
        for reg in self.regs.values():
            if reg.d.object is not None:
                name = object_name(reg.d.object)
                if name is not None:
                    out[name] = reg
        return out

    def _generated(self) -> dict[str, RegisterDef]:
        """Registers for the objects ``[cia402]`` places by its address rule."""
        from drivebus.drives.cia402 import OBJECTS

        c = self.cia402
        if c is None or c.address_rule is None:
            return {}
        taken = {object_name(d.object) for d in self.registers.values() if d.object}
        out: dict[str, RegisterDef] = {}
        for ref in c.objects:
            name = object_name(ref)
            if name is None or name in taken or name in self.registers:
                continue
            info = OBJECTS[name]
            try:
                address = int(c.address_rule({"index": info.index, "sub": info.subindex}))
            except (ExprError, TypeError, ValueError):
                continue  # reported by the checks
            kind = _object_kind(name)
            unit = getattr(c, kind) if kind else None
            out[name] = RegisterDef(
                address=address, words=2 if info.bits > 16 or c.words == 2 else 1,
                signed=info.signed,
                access="RW" if info.writable else "R", object=name,
                unit=unit.unit if unit else "", scale=unit.scale if unit else 1.0,
                name=info.text)
        return out

    @property
    def family(self) -> str:
        """The family name."""
        return self.drive.family

    @cached_property
    def status_exprs(self) -> dict[str, Expr]:
        """How each ``DriveStatus`` field decodes: ``[status]``'s expression, else one made
        from what the polled registers and bits *mean* (``means``), else ``enabled`` is
        taken as true (a drive that does not report it) and the others are absent."""
        s = self.status
        out: dict[str, Expr] = {}
        bits: dict[str, list[str]] = {}
        regs: dict[str, list[str]] = {}
        for reg in self.regs.values():
            if reg.d.access == "W" or reg.array:
                continue
            if reg.d.means and (reg.d.coil or reg.d.discrete):
                bits.setdefault(reg.d.means, []).append(reg.key)  # a one-bit state
            elif reg.d.means:
                regs.setdefault(reg.d.means, []).append(reg.key)
            for name, b in reg.d.bits.items():
                if b.means:
                    bits.setdefault(b.means, []).append(f"{reg.key}.{name}")

        def any_of(pos: str, neg: str | None = None) -> str | None:
            terms = list(bits.get(pos, []))
            if neg is not None:
                terms += [f"not {t}" for t in bits.get(neg, [])]
            return " or ".join(terms) or None

        derived: dict[str, str | None] = {
            "enabled": any_of("enabled", "disabled"),
            "moving": any_of("moving", "at_rest") or any_of("jogging"),
            "homed": any_of("homed"),
            "homing": any_of("homing"),
            "homing_error": any_of("homing_error"),
            "alarm": " or ".join(filter(None, [any_of("alarm", "no_alarm")] + [
                f"{k} != 0" for k in regs.get("alarm_code", [])])) or None,
            "alarm_code": (regs.get("alarm_code") or [None])[0],
            "position": (regs.get("position") or [None])[0],
            "velocity": (regs.get("velocity") or [None])[0],
        }
        for side in ("limit_positive", "limit_negative"):
            io = self.inputs
            if io is not None and (side in io.codes or side in io.bits):
                derived[side] = f"input.{side}"
            else:
                derived[side] = any_of(side)
        moving = s.moving.source if s.moving is not None else derived["moving"]
        alarm = s.alarm.source if s.alarm is not None else derived["alarm"]
        reached = any_of("in_position")
        if reached and moving:
            derived["in_position"] = f"({reached}) and not ({moving})"
        elif reached:
            derived["in_position"] = reached
        elif moving:
            derived["in_position"] = f"not ({moving})" + (f" and not ({alarm})" if alarm else "")
        else:
            derived["in_position"] = None
        for field, text in derived.items():
            given = getattr(s, field)
            if given is not None:
                out[field] = given
            elif text is not None:
                out[field] = Expr.parse(text)
        out.setdefault("enabled", Expr.parse(True))
        return out

    def parameter_regs(self) -> list[tuple[str, Reg, int | None]]:
        """The documented settings (key, register, table index) ``drivebus params`` backs
        up, in address order: each register's ``parameter`` flag or key, else every
        read/write register that is not volatile, shows no state and is not the EEPROM
        write-through switch."""
        wt = self.eeprom.write_through
        out = []
        for key, reg in self.regs.items():
            d = reg.d
            wanted = d.parameter if d.parameter is not None else (
                d.access == "RW" and not d.volatile and d.means is None
                and (wt is None or wt.reg != key))
            if wanted is False:
                continue
            for i in reg.indices if reg.array else [None]:
                out.append((self._parameter_key(key, reg, i), reg, i))
        return sorted(out, key=lambda kri: kri[1].at(kri[2]).address)

    @staticmethod
    def _parameter_key(key: str, reg: Reg, index: int | None) -> str:
        given = reg.d.parameter if isinstance(reg.d.parameter, str) else None
        if index is None:
            return given or key
        name = reg.d.names[index - reg.d.first] if reg.d.names else str(index)
        if given is None:
            return f"{key}_{index}"
        return given.format(i=index, name=_KeyName(name))

    def procedure_what(self, name: str) -> str:
        """How a NotSupported error says procedure ``name``."""
        if name in PROCEDURES:
            return PROCEDURES[name][0]
        proc = self.procedures.get(name)
        if proc is not None and proc.what is not None and not proc.what.names:
            return str(proc.what)
        return name.replace("_", " ")


class _KeyName(str):
    """A table entry's name in a parameter key: ``{name}``, ``{name:lower}``, ``{name:upper}``."""

    __slots__ = ()

    def __format__(self, spec: str) -> str:
        if spec == "lower":
            return self.lower()
        if spec == "upper":
            return self.upper()
        return format(str(self), spec)


# -- loading and checking -------------------------------------------------------------------


def parse_description(data: Mapping[str, Any], source: str = "description") -> Description:
    """Validate a description mapping; one ``ConfigError`` names ``source``, each key
    path and the problem."""
    data = _numbered(data, source)
    try:
        desc = Description.model_validate(dict(data))
    except ValidationError as exc:
        problems = "; ".join(validation_problems(exc, model=Description, limit=8))
        raise ConfigError(f"{source}: {problems}") from None
    problems = list(_Checker(desc).problems())
    if problems:
        shown = problems[:8] + ([f"and {len(problems) - 8} more"] if len(problems) > 8 else [])
        raise ConfigError(f"{source}: {'; '.join(shown)}")
    return desc


def _numbered(data: Mapping[str, Any], source: str) -> dict[str, Any]:
    """``data`` with each register address given as the manual's parameter number
    (``address = "P5-07"``) replaced by the address ``[link] parameter_numbers`` gives it;
    one ``ConfigError`` naming the register's key otherwise."""
    registers = data.get("registers")
    out = dict(data)
    if not isinstance(registers, dict) or not any(
            isinstance(r, dict) and any(isinstance(r.get(f), str) for f in _NUMBERED)
            for r in registers.values()):
        return out
    link = data.get("link", {})
    rule = link.get("parameter_numbers") if isinstance(link, dict) else None
    try:
        numbers = ParameterNumbers.model_validate(rule) if rule is not None else None
    except ValidationError as exc:
        problems = "; ".join(validation_problems(exc, model=ParameterNumbers,
                                                 prefix="link.parameter_numbers"))
        raise ConfigError(f"{source}: {problems}") from None
    resolved = {}
    for key, reg in registers.items():
        if isinstance(reg, dict):
            reg = dict(reg)
            for f in _NUMBERED:
                number = reg.get(f)
                if not isinstance(number, str):
                    continue
                if numbers is None:
                    raise ConfigError(
                        f"{source}: registers.{key}.{f}: {number!r} is not an address: give "
                        "a number (6, 0x0006) or, where the manual numbers its parameters "
                        "(a parameter number such as 'P5-07'), say how numbers give "
                        "addresses in [link] parameter_numbers = { pattern = "
                        "'P{group}-{number}', address = 'group * 0x100 + number * 2' }")
                try:
                    reg[f] = numbers.resolve(number)
                except (ValueError, ExprError) as exc:
                    raise ConfigError(f"{source}: registers.{key}.{f}: {exc}") from None
                if f == "address":
                    reg.setdefault("name", number)
        resolved[key] = reg
    out["registers"] = resolved
    return out


_NUMBERED = ("address", "low_address")
_SPACE_NAMES = ("a holding register", "an input register", "a coil", "a discrete input")
"""What a register of each address space (``Reg.space``) is, in errors."""


def read_toml(p: Path, noun: str) -> dict[str, Any]:
    """The TOML file ``p`` (a ``noun``: "drive description", "config file") as a mapping;
    one ``ConfigError`` naming the file when it is missing, unreadable or not TOML."""
    try:
        return tomllib.loads(p.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise ConfigError(f"{p}: no such {noun}") from None
    except UnicodeDecodeError as exc:
        raise ConfigError(f"{p}: not a text file (not UTF-8 at byte {exc.start})") from None
    except OSError as exc:
        raise ConfigError(f"{p}: cannot read the {noun}: {exc.strerror or exc}") from None
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(f"{p}: not valid TOML: {exc}") from None


def _extended(data: dict[str, Any], p: Path, seen: tuple[Path, ...] = ()) -> dict[str, Any]:
    """``data`` over the description it ``extends`` (a file relative to ``p``): each
    section's keys replace the base's whole (a register, an option, a procedure,
    ``homing.methods``, a ``[link]`` key), and ``remove = { registers = [...] }`` drops
    entries of the base."""
    ref = data.pop("extends", None)
    remove = data.pop("remove", {})
    if ref is None:
        if remove:
            raise ConfigError(f"{p}: remove: only a description that extends another removes")
        return data
    if not isinstance(ref, str):
        raise ConfigError(f"{p}: extends: expected a file name, got {ref!r}")
    base_path = (p.parent / ref).resolve()
    if base_path in seen:
        raise ConfigError(f"{p}: extends: {ref} extends it in turn")
    base = _extended(read_toml(base_path, "drive description"), base_path, (*seen, p.resolve()))
    out = dict(base)
    for section, value in data.items():
        old = out.get(section)
        if not isinstance(value, dict) or not isinstance(old, dict):
            out[section] = value
        else:
            out[section] = {**old, **value}
    if not isinstance(remove, dict):
        raise ConfigError(f"{p}: remove: expected a table of section = [keys]")
    for section, keys in remove.items():
        entries = dict(out.get(section, {}))
        for key in keys if isinstance(keys, list) else [keys]:
            if key not in entries:
                raise ConfigError(f"{p}: remove.{section}: {ref} has no {section}.{key}")
            del entries[key]
        out[section] = entries
    return out


def load_description(path: str | Path) -> Description:
    """Read and check the description file ``path`` (over the one it ``extends``)."""
    p = Path(path)
    data = _extended(read_toml(p, "drive description"), p)
    return parse_description(data, str(p))


_CONTEXT_NAMES = {
    "option", "state", "last", "words", "input", "output", "home", "pulses_per_rev",
    "value", "raw", "True", "False", "None", "input_functions", "output_functions",
}
_TWIN_NAMES = {"enabled", "moving", "alarm", "homed", "motion", "value", "previous", "raw",
               "speed_now", "pulses_per_rev", "limit_positive", "limit_negative", "motion_decel",
               "homing", "stopping", "active", "at_speed", "stalled", "cruising"}


class _Checker:
    """The cross-checks pydantic cannot make: every name an expression uses exists, every
    register key named exists, tables and ramps refer to what they should."""

    def __init__(self, d: Description) -> None:
        self.d = d
        self.regs = d.regs
        self.out: list[str] = []

    def problems(self) -> Iterator[str]:
        d = self.d
        self._registers()
        self._units()
        self._identify()
        self._status()
        self._io("inputs", d.inputs)
        self._io("outputs", d.outputs)
        if d.alarms is not None:
            self._reg_key("alarms.register", d.alarms.reg)
        for name, sig in d.signals.items():
            self._reg_key(f"signals.{name}.register", sig.reg)
        called = {step.call for proc in d.procedures.values() for step in proc.steps
                  if step.call is not None}
        for name, proc in d.procedures.items():
            self._procedure(name, proc)
            known = [*PROCEDURES, *EXTRA_PROCEDURES]
            close = difflib.get_close_matches(name, known, n=1, cutoff=0.8)
            if name not in known and name not in called and close:
                # the drive's own procedure (profile.NAME), but named like a common one
                self.out.append(f"procedures.{name}: did you mean {close[0]!r}? (the engine "
                                f"runs {close[0]}; a procedure of the drive's own needs a "
                                "name of its own)")
        for i, oc in enumerate(d.option_checks):
            self._names(f"option_checks[{i}].check", oc.check)
            self._names(f"option_checks[{i}].message", oc.message)
        self._programs()
        self._twin()
        if d.link.format_register is not None:
            self._reg_key("link.format_register", d.link.format_register)
        if d.link.baud_register is not None:
            self._reg_key("link.baud_register", d.link.baud_register)
        if d.link.address_register is not None:
            self._reg_key("link.address_register", d.link.address_register)
        if d.eeprom.write_through is not None:
            self._reg_key("eeprom.write_through.register", d.eeprom.write_through.reg)
        self._cia402()
        self._parameters()
        self._examples()
        yield from self.out

    def _examples(self) -> None:
        for i, ex in enumerate(self.d.examples):
            where = f"examples[{i}]"
            for frame in [*ex.request, *ex.reply]:
                if not re.fullmatch(r"\s*(?:(?:0x)?[0-9A-Fa-f]{2}h?[\s,]*)+", frame):
                    self.out.append(f"{where}: {frame!r} is not a frame of hex bytes "
                                    f"('01 06 00 1D 02 58 D9 8B')")
                    break
            for key in ex.write or {}:
                self._target(f"{where}.write", key, set(), writes=True)
            for item in ex.read or []:
                if isinstance(item, str) and "[" in item:
                    self._target(f"{where}.read", item, set())
                else:
                    self._span(f"{where}.read", item)
            read_keys = {k for item in ex.read or [] for k in
                         ([item] if isinstance(item, str) else item)}
            for key in ex.values:
                if key not in read_keys and ex.read and not any(
                        isinstance(item, list) for item in ex.read):
                    self.out.append(f"{where}.values.{key}: not one of the registers read")
            if ex.procedure is not None and ex.procedure not in self.d.procedures and \
                    (self.d.drive.engine != "cia402" or ex.procedure not in PROCEDURES):
                self.out.append(f"{where}.procedure: no procedure {ex.procedure!r}")

    def _programs(self) -> None:
        proc = self.d.procedures.get("retarget_absolute")
        if self.d.programs.retarget and (proc is None or proc.unsupported is not None):
            self.out.append("programs.retarget: needs procedures.retarget_absolute (the steps "
                            "that give a running move its new target)")

    def _parameters(self) -> None:
        seen: dict[str, str] = {}
        for pkey, reg, index in self.d.parameter_regs():
            where = reg.key if index is None else f"{reg.key}[{index}]"
            other = seen.setdefault(pkey, where)
            if other != where:
                self.out.append(f"registers.{reg.key}.parameter: key {pkey!r} is also "
                                f"registers.{other}'s")

    # -- registers --------------------------------------------------------------------------

    def _registers(self) -> None:
        if not self.regs:
            self.out.append("registers: none given (a description needs at least one)")
        owner: dict[int, str] = {}
        for key, given in self.d.registers.items():
            base = self.d.register_base(given)
            for field in ("address", "low_address"):
                number = getattr(given, field)
                if number is not None and number < base:
                    self.out.append(
                        f"registers.{key}.{field}: {number} is below the first register, "
                        f"{base} (link.register_base = {self.d.link.register_base}: "
                        f"addresses are the manual's numbers)")
        for key, reg in self.regs.items():
            where = f"registers.{key}"
            d = reg.d
            if d.ramp is not None and isinstance(d.ramp, str):
                ref = self.regs.get(d.ramp)
                if ref is None:
                    self.out.append(f"{where}.ramp: no register {d.ramp!r}")
                elif ref.codec.kind is not Kind.SPEED:
                    self.out.append(f"{where}.ramp: register {d.ramp} holds no speed (give it "
                                    f"a speed unit: rpm, rps, pulses/s)")
            if d.ramp is not None and d.unit not in ("ms", "s"):
                self.out.append(f"{where}.unit: a ramp time is in 'ms' or 's', not {d.unit!r}")
            try:
                Register(reg.name, d.address, d.words, signed=d.signed, minimum=d.min,
                         maximum=d.max)
            except ConfigError as exc:
                self.out.append(f"{where}: {exc}")
            lo, hi = reg.register.lo, reg.register.hi
            if (d.min is not None and d.min < _width_lo(d)) or (d.max is not None and \
                    d.max > _width_hi(d)):
                self.out.append(f"{where}: range {lo}..{hi} does not fit {16 * d.words} "
                                f"{'signed' if d.signed else 'unsigned'} bits")
            if d.offset and not reg.objects:
                self.out.append(f"{where}.offset: an offset is for a sub-index of an "
                                f"object-addressed map ([link] map = \"objects\")")
            space = reg.space << 24  # inputs, coils and discrete inputs: spaces apart
            for a in reg.addresses():
                shown = a >> 8 if reg.objects else a
                if shown > 0xFFFF:
                    self.out.append(f"{where}: its words reach address {shown}, beyond 65535")
                    break
                if space + a in owner and owner[space + a] != key:
                    word = f", word {a & 0xFF} of the object" if reg.objects else ""
                    self.out.append(f"{where}.address: address {shown} (0x{shown:04X}{word}) "
                                    f"is also register {owner[space + a]}")
                    break
                owner[space + a] = key

    def _cia402(self) -> None:
        d = self.d
        for key, r in d.registers.items():
            if r.object is not None and object_name(r.object) is None:
                self.out.append(f"registers.{key}.object: {r.object!r} is not a CiA 402 "
                                f"object drivebus knows (see drivebus.drives.cia402.OBJECTS)")
        c = d.cia402
        if c is not None:
            for i, ref in enumerate(c.objects):
                if object_name(ref) is None:
                    self.out.append(f"cia402.objects[{i}]: {ref!r} is not a CiA 402 object")
            if c.objects and c.address_rule is None:
                self.out.append("cia402.objects: needs address_rule (how an object's index "
                                "and sub-index give its address)")
            self._cia402_blocks(c)
            if c.address_rule is not None:
                unknown = c.address_rule.names - {"index", "sub"} - set(FUNCTIONS)
                if unknown:
                    self.out.append(f"cia402.address_rule: {c.address_rule.source!r} may use "
                                    f"only index and sub, not {', '.join(sorted(unknown))}")
                self._placed_overlaps()
        spaces = {r.space for r in self.regs.values()}
        for space, fc, what in ((0, 3, "holding registers"), (1, 4, "input registers"),
                                (2, 1, "coils"), (3, 2, "discrete inputs")):
            if space in spaces and fc not in d.link.functions:
                self.out.append(f"link.functions: {what} need function code {fc}")
        if d.link.map == "objects" and 16 not in d.link.functions and any(
                r.d.words == 2 or r.d.offset for r in self.regs.values()):
            self.out.append("link.functions: an object-addressed map writes a 32-bit object "
                            "or a sub-index with function code 16 (its words go with its one "
                            "address)")
        if any(r.d.coil and r.d.access != "R" for r in self.regs.values()) and \
                5 not in d.link.functions:
            self.out.append("link.functions: writing coils needs function code 5")
        if d.drive.engine == "cia402":
            for needed in ("controlword", "statusword"):
                if needed not in d.objects:
                    self.out.append(f"registers: the CiA 402 engine needs the {needed} "
                                    f"(a register with object = \"{needed}\")")
        elif c is not None:
            self.out.append("cia402: only for drive.engine = \"cia402\"")

    def _cia402_blocks(self, c: Cia402Def) -> None:
        from drivebus.drives.mapping import adjacent

        seen: dict[str, int] = {}
        for i, block in enumerate(c.blocks):
            regs = []
            for ref in block:
                name = object_name(ref)
                if name is None or name not in self.d.objects:
                    self.out.append(f"cia402.blocks[{i}]: {ref!r} is no object mapped to a "
                                    f"register")
                    return
                if name in seen:
                    self.out.append(f"cia402.blocks[{i}]: {name} is also in "
                                    f"cia402.blocks[{seen[name]}]")
                seen[name] = i
                regs.append(self.d.objects[name])
            gap = adjacent(regs)
            if gap is not None:
                self.out.append(f"cia402.blocks[{i}]: {gap[0]} and {gap[1]} are not "
                                f"adjacent, so one FC16 cannot write them")

    def _placed_overlaps(self) -> None:
        """Registers the address rule places must not share an address with another."""
        placed = self.d._generated()
        owner: dict[int, str] = {}
        for key, reg in self.d.regs.items():
            if reg.space != 0:
                continue
            for a in reg.addresses():
                other = owner.setdefault(a, key)
                if other != key and (key in placed or other in placed):
                    self.out.append(f"cia402.address_rule: {other} and {key} both take "
                                    f"register {a} (the rule must space the objects by the "
                                    f"registers each takes)")
                    return

    def _units(self) -> None:
        ppr = self.d.units.pulses_per_rev
        if ppr.reg is not None:
            self._reg_key("units.pulses_per_rev.register", ppr.reg)

    def _reg_key(self, where: str, key: str) -> None:
        base = key.split("[", 1)[0]
        if base not in self.regs:
            self.out.append(f"{where}: no register {base!r} (registers: {_some(self.regs)})")

    # -- expressions --------------------------------------------------------------------------

    def _names(self, where: str, expr: Expr | Template | None, extra: Iterable[str] = ()) -> None:
        """Every name ``expr`` uses must be known in its context."""
        if expr is None:
            return
        d = self.d
        known = set(self.regs) | set(d.constants) | _CONTEXT_NAMES | set(FUNCTIONS) | set(extra)
        for name in sorted(expr.names - known):
            self.out.append(f"{where}: {expr.source!r} uses {name!r}, which is no register, "
                            f"constant, option or parameter")
        for path in sorted(expr.paths):
            head, _, rest = path.partition(".")
            attr = rest.split(".", 1)[0]
            if not attr:
                continue
            if head == "option" and attr not in d.options:
                self.out.append(f"{where}: {expr.source!r}: no option {attr!r} (options: "
                                f"{_some(d.options)})")
            elif head == "state" and attr not in d.state:
                self.out.append(f"{where}: {expr.source!r}: no state variable {attr!r} "
                                f"(declare it in [state])")
            elif head in ("last", "words") and attr not in self.regs:
                self.out.append(f"{where}: {expr.source!r}: no register {attr!r}")
            elif head in self.regs and head not in extra:
                reg = self.regs[head]
                if attr not in reg.d.bits and attr not in reg.d.values:
                    self.out.append(f"{where}: {expr.source!r}: register {head} has no bit "
                                    f"or value {attr!r}")

    def _identify(self) -> None:
        ident = self.d.identify
        if ident is None:
            return
        for i, key in enumerate(ident.read):
            self._reg_key(f"identify.read[{i}]", key)
        self._names("identify.match", ident.match)
        self._names("identify.model", ident.model)
        self._names("identify.firmware", ident.firmware)
        for k, e in ident.raw.items():
            self._names(f"identify.raw.{k}", e)

    def _span(self, where: str, item: str | list[str]) -> None:
        keys = [item] if isinstance(item, str) else item
        if isinstance(item, list) and len(item) != 2:
            self.out.append(f"{where}: a span is [first, last] register")
        if isinstance(item, list) and self.d.link.map == "objects":
            self.out.append(f"{where}: an object-addressed map reads each object by itself: "
                            f"list the registers, not a span")
        for k in keys:
            self._reg_key(where, k)
        ends = [self.d.regs.get(k.split("[", 1)[0].strip()) for k in keys]
        if isinstance(item, list) and len(ends) == 2 and None not in ends:
            first, last = ends
            assert first is not None and last is not None
            if first.space != last.space:
                self.out.append(
                    f"{where}: a span reads one address space; {first.key} is "
                    f"{_SPACE_NAMES[first.space]} and {last.key} {_SPACE_NAMES[last.space]}")

    def _status(self) -> None:
        s = self.d.status
        for i, item in enumerate(s.poll):
            self._span(f"status.poll[{i}]", item)
        for i, extra in enumerate(s.extra):
            for j, item in enumerate(extra.read):
                self._span(f"status.extra[{i}].read[{j}]", item)
            self._names(f"status.extra[{i}].when", extra.when)
        for field in ("enabled", "moving", "in_position", "homed", "homing", "homing_error",
                      "alarm", "alarm_code", "limit_positive", "limit_negative", "position",
                      "velocity"):
            self._names(f"status.{field}", getattr(s, field))
        for k, e in s.raw.items():
            self._names(f"status.raw.{k}", e)
        if s.completion is not None:
            for j, item in enumerate(s.completion.read):
                self._span(f"status.completion.read[{j}]", item)
            for field in ("moving", "in_position", "alarm", "limit_positive", "limit_negative"):
                self._names(f"status.completion.{field}", getattr(s.completion, field))
        for k, e in s.track.items():
            self._names(f"status.track.{k}", e)
            if k not in self.d.state:
                self.out.append(f"status.track.{k}: no state variable {k!r} (declare it in "
                                f"[state])")

    def _io(self, where: str, io: IoDef | None) -> None:
        if io is None:
            return
        self._reg_key(f"{where}.state", io.state)
        for k in ("invert", "functions", "polarity"):
            v = getattr(io, k)
            if v is not None:
                self._reg_key(f"{where}.{k}", v)
        if io.functions is None and io.codes:
            self.out.append(f"{where}.codes: function codes need 'functions' (the registers "
                            f"that assign them); give fixed wiring with 'bits'")
        if io.functions is None and io.function_names:
            self.out.append(f"{where}.function_names: function names need 'functions' (the "
                            f"registers that assign them)")
        state = self.regs.get(io.state)
        if state is not None and len(io.names) > 16 * state.d.words:
            self.out.append(f"{where}.names: {len(io.names)} terminals for the "
                            f"{16 * state.d.words} bits of register {io.state}")
        funcs = self.regs.get(io.functions) if io.functions is not None else None
        if funcs is not None and io.names and len(io.names) != funcs.d.count:
            self.out.append(f"{where}.names: {len(io.names)} terminals, but register "
                            f"{io.functions} assigns {funcs.d.count} functions")
        if len(set(n.upper() for n in io.names)) != len(io.names):
            self.out.append(f"{where}.names: a terminal is named twice")

    def _procedure(self, name: str, proc: Procedure) -> None:
        where = f"procedures.{name}"
        params = set(PROCEDURES.get(name, ("", ()))[1]) | {p.name for p in proc.params}
        for i, taken in enumerate(proc.takes or []):
            if taken not in params:
                self.out.append(f"{where}.takes[{i}]: {taken!r} is no parameter of {name} "
                                f"({', '.join(sorted(params)) or 'it has none'})")
        self._names(f"{where}.supported", proc.supported)
        self._names(f"{where}.what", proc.what, params)
        if name == "learn":
            for i, step in enumerate(proc.steps):
                if step.action not in ("read", "set"):
                    self.out.append(f"{where}.steps[{i}]: learn only reads (it runs when a "
                                    f"viewing command opens the drive); write in setup")
        for i, step in enumerate(proc.steps):
            self._step(f"{where}.steps[{i}]", step, params)

    def _step(self, where: str, step: Step, params: set[str]) -> None:
        for field in ("when", "block", "check", "wait", "return_", "bits_set", "bits_clear",
                      "bits_toggle", "timeout"):
            self._names(f"{where}.{field.rstrip('_')}", getattr(step, field), params)
        self._names(f"{where}.fail", step.fail, params)
        self._names(f"{where}.message", step.message, params)
        if step.write is not None:
            if step.each is not None:
                name, _, source = step.each.partition(" in ")
                self._names(f"{where}.each", Expr.parse(source), params)
                params = params | {name.strip()}
            for key, item in step.write.items():
                self._target(f"{where}.write", key, params, writes=True)
                self._names(f"{where}.write.{key}", item.value, params)
            if step.block is not None and step.each is None:
                self._block(where, list(step.write))
        if step.read is not None:
            for j, item in enumerate(step.read):
                if isinstance(item, str) and "[" in item:
                    self._target(f"{where}.read[{j}]", item, params)
                else:
                    self._span(f"{where}.read[{j}]", item)
        if step.modify is not None:
            self._target(f"{where}.modify", step.modify, params, writes=True)
            reg = self.regs.get(step.modify.split("[", 1)[0].strip())
            if reg is not None and reg.space in (2, 3):
                self.out.append(f"{where}.modify: {reg.key} is a coil or discrete input: "
                                f"write it (0/1) instead")
        if step.call is not None and step.call not in self.d.procedures:
            self.out.append(f"{where}.call: no procedure {step.call!r}")
        for k, e in step.args.items():
            self._names(f"{where}.args.{k}", e, params)
        if step.set is not None:
            for k, e in step.set.items():
                if k not in self.d.state:
                    self.out.append(f"{where}.set.{k}: no state variable {k!r} (declare it "
                                    f"in [state])")
                self._names(f"{where}.set.{k}", e, params)

    def _block(self, where: str, keys: list[str]) -> None:
        """A step's ``block``: its registers must follow on from each other in the order
        listed (one FC16 writes them; anything else would merge what the manual keeps
        apart, or silently become several writes)."""
        from drivebus.drives.mapping import adjacent

        pairs: list[tuple[Reg, int | None]] = []
        for key in keys:
            m = re.fullmatch(r"([A-Za-z_][A-Za-z0-9_]*)(?:\[\s*(\d+)\s*\])?", key.strip())
            reg = self.regs.get(m.group(1)) if m is not None else None
            if m is None or reg is None or (reg.array and m.group(2) is None):
                return  # an index only the run knows, or a mistake named elsewhere
            index = int(m.group(2)) if m.group(2) is not None else None
            if index is not None and (not reg.array or index not in reg.indices):
                return
            pairs.append((reg, index))
        gap = adjacent(pairs)
        if gap is not None:
            self.out.append(
                f"{where}.block: {gap[0]} and {gap[1]} are not adjacent, so one FC16 "
                f"cannot write them: list a block's registers in address order with no "
                f"gap (and only where the manual lets them be written together), or "
                f"write them in separate steps")

    def _target(self, where: str, key: str, params: set[str], *, writes: bool = False
                ) -> None:
        """A register a step names: ``key`` or ``key[index expression]`` (with ``writes``:
        one the drive takes writes to)."""
        m = re.fullmatch(r"([A-Za-z_][A-Za-z0-9_]*)(?:\[(.+)\])?", key.strip())
        if m is None:
            self.out.append(f"{where}: {key!r} is not a register (KEY or KEY[index])")
            return
        base, index = m.groups()
        if base not in self.regs:
            self.out.append(f"{where}: no register {base!r} (registers: {_some(self.regs)})")
            return
        reg = self.regs[base]
        if writes and (reg.d.access == "R" or reg.space in (1, 3)):
            self.out.append(f"{where}: register {base} is read-only (access = \"R\", an input "
                            "register or a discrete input): a procedure cannot write it")
            return
        if index is None and reg.array:
            self.out.append(f"{where}: register {base} is a table: name an entry, "
                            f"{base}[index]")
        if index is not None:
            if not reg.array:
                self.out.append(f"{where}: register {base} is not a table")
            try:
                self._names(f"{where}", Expr.parse(index), params)
            except ExprError as exc:
                self.out.append(f"{where}: {exc}")

    def _twin(self) -> None:
        t = self.d.twin
        names = _TWIN_NAMES
        for key, reg in self.d.registers.items():
            self._names(f"registers.{key}.valid", reg.valid, names)
        io = self.d.inputs
        for signal, terminal in t.wiring.items():
            if io is None:
                self.out.append(f"twin.wiring.{signal}: needs [inputs]")
            elif isinstance(terminal, str) and terminal not in io.names:
                self.out.append(f"twin.wiring.{signal}: no terminal {terminal!r} in "
                                f"inputs.names ({', '.join(io.names) or 'none'})")
        self._names("twin.starts", t.starts, names)
        self._names("twin.limits.stop", t.limits.stop, names)
        self._names("twin.limits.decel", t.limits.decel, names)
        self._names("twin.eeprom_write_through", t.eeprom_write_through, names)
        self._names("twin.enabled", t.enabled, names)
        self._names("twin.stall_time", t.stall_time, names)
        self._names("twin.homing.reverse_at_limit", t.homing.reverse_at_limit, names)
        self._names("twin.homing.offset", t.homing.offset, names)
        for key, reg in self.d.registers.items():
            for bit, b in reg.bits.items():
                self._names(f"registers.{key}.bits.{bit}.twin", b.twin, names)
        for i, key in enumerate(t.options):
            self._reg_key(f"twin.options[{i}]", key)
        out = self.d.outputs
        if out is not None and out.values is not None:
            self._reg_key("outputs.values", out.values)
        codes = io.codes if io is not None else {}
        for i, itrig in enumerate(t.on_input):
            if itrig.input not in codes:
                self.out.append(f"twin.on_input[{i}].input: no input function "
                                f"{itrig.input!r} in inputs.codes ({', '.join(codes) or 'none'})")
        triggers = [(f"twin.on_write[{i}]", trig) for i, trig in enumerate(t.on_write)]
        triggers += [(f"twin.on_input[{i}]", trig) for i, trig in enumerate(t.on_input)]
        for where, trig in triggers:
            if trig.reg or not isinstance(trig, InputTrigger):
                self._reg_key(f"{where}.register", trig.reg)
            self._names(f"{where}.when", trig.when, names)
            for kind, sets in (("set", trig.set), ("ends", trig.ends)):
                for key, e in sets.items():
                    self._reg_key(f"{where}.{kind}.{key}", key)
                    self._names(f"{where}.{kind}.{key}", e, names)
            allowed = TWIN_ACTIONS[trig.do]
            row_names = names | {"row"} if trig.do == "run_table" else names
            for field in ("target", "distance", "speed", "accel", "decel", "creep", "method",
                          "offset", "position", "rows", "wait", "repeat"):
                e = getattr(trig, field)
                if e is None:
                    continue
                if field not in allowed:
                    self.out.append(f"{where}.{field}: action {trig.do} takes "
                                    f"{', '.join(allowed) or 'no parameters'}")
                self._names(f"{where}.{field}", e, row_names)
            if trig.do == "run_table" and (trig.rows is None or trig.speed is None or
                                           (trig.target is None and trig.distance is None)):
                self.out.append(f"{where}: run_table needs rows, speed and a target or "
                                "distance")


def _object_kind(name: str) -> str | None:
    """Which of ``[cia402]``'s units an object's registers take."""
    if name in ("position_actual_value", "target_position", "home_offset"):
        return "position"
    if name in ("velocity_actual_value", "profile_velocity", "target_velocity",
                "homing_speed_search", "homing_speed_zero"):
        return "velocity"
    if name in ("profile_acceleration", "profile_deceleration", "quick_stop_deceleration",
                "homing_acceleration"):
        return "acceleration"
    return None


def _width_lo(d: RegisterDef) -> int:
    bits = 16 * d.words
    return -(1 << (bits - 1)) if d.signed else 0


def _width_hi(d: RegisterDef) -> int:
    bits = 16 * d.words
    return (1 << (bits - 1)) - 1 if d.signed else (1 << bits) - 1


def _some(keys: Iterable[str], n: int = 12) -> str:
    ks = list(keys)
    return ", ".join(ks[:n]) + (", ..." if len(ks) > n else "") if ks else "none"
