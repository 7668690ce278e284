"""The sections that say what the drive reports: ``[status]`` (the poll and how it
decodes into ``DriveStatus``), ``[inputs]``/``[outputs]``, ``[alarms]`` and
``[signals]``.
"""

from __future__ import annotations

from typing import Annotated, Literal

from pydantic import Field

from drivebus.drives.description.fields import SECTION_SOURCE, E, IntKeyed, Source, T, _Model
from drivebus.drives.expr import Template


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
    source: Source | None = Field(None, description=SECTION_SOURCE)


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
    source: Source | None = Field(None, description=SECTION_SOURCE)


class SignalDef(_Model):
    """A further value read in its own poll group (temperature, bus voltage, ...)."""

    reg: str = Field(alias="register")
    every: float = Field(1.0, gt=0, le=3600, description="s")
    doc: str = ""
