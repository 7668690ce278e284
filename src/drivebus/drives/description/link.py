"""``[drive]``, ``[identify]`` and ``[link]``: who the drive is, how a scan knows it and
how it is reached (addresses, baud rates, formats, function codes, word order,
register numbering, exception codes, timing).
"""

from __future__ import annotations

import re
from typing import Annotated, Any, Literal

from pydantic import Field, ValidationInfo, field_validator, model_validator

from drivebus.drives.description.fields import SECTION_SOURCE, E, IntKeyed, Source, T, _Model
from drivebus.drives.expr import FUNCTIONS, Template
from drivebus.drives.registers import WordOrder
from drivebus.settings import LineSettings

_SENT_FUNCTIONS = frozenset({1, 2, 3, 4, 5, 6, 16})
"""The function codes drivebus sends: what a description's ``[link] functions`` keeps of
the manual's list (the others, 08 diagnostics, 15, 23, ..., are left out)."""


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
    source: Source | None = Field(None, description=SECTION_SOURCE)

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
    split: int | None = Field(None, ge=1, le=255, description="a request that starts or ends "
                              "inside a 32-bit value, where the drive reads and writes its "
                              "values whole (else half a value is answered)")


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
    words: Literal[1, 2] = Field(1, description="the width of every register that gives no "
                                 "words of its own (2: a drive that stores every value in two "
                                 "registers, its 16-bit ones too); coils and discrete inputs "
                                 "are one bit")
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
    source: Source | None = Field(None, description=SECTION_SOURCE)

    @field_validator("functions", mode="before")
    @classmethod
    def _functions(cls, v: Any) -> Any:
        if isinstance(v, list):  # the manual's list as it is: keep the codes drivebus sends
            wrong = [f for f in v if not isinstance(f, int) or isinstance(f, bool)
                     or not 1 <= f <= 127]
            if wrong:
                raise ValueError(f"{', '.join(map(repr, wrong))}: not a Modbus function code "
                                 f"(1..127)")
            return [f for f in dict.fromkeys(v) if f in _SENT_FUNCTIONS]
        return v

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
        return tuple(v) if isinstance(v, list) else v  # (TOML has no tuples)

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
            f = LineSettings.parse(self.factory)
            if self.baud_rates and f.baudrate not in self.baud_rates:
                raise ValueError(f"factory: {self.factory!r} is at {f.baudrate} baud, which is "
                                 f"not among the drive's baud_rates {self.baud_rates}")
            if self.formats and f.format not in self.formats:
                raise ValueError(f"factory: {self.factory!r} is in {f.format}, which is not "
                                 f"among the drive's formats {self.formats}")
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
