"""The sections that say what the drive is set to and offers: ``[options]`` (its
``drive_options``) and ``option_checks``, ``[units]``, ``[eeprom]`` and ``[programs]``.
"""

from __future__ import annotations

from typing import Any, Literal

from pydantic import Field, field_validator, model_validator

from drivebus.drives.description.fields import E, T, _Model
from drivebus.drives.programs import ProgramSupport


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

    @field_validator("range", mode="before")
    @classmethod
    def _pair(cls, v: object) -> object:
        return tuple(v) if isinstance(v, list) else v  # (TOML has no tuples)


class Units(_Model):
    """``[units]``."""

    pulses_per_rev: PulsesPerRev


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
