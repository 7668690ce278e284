"""Serial line settings: baud rate and character format, validated once at the edge."""

from __future__ import annotations

import re
from typing import Any, Literal

from pydantic import (
    BaseModel,
    ConfigDict,
    Field,
    StrictInt,
    ValidationError,
    ValidationInfo,
    field_validator,
)

from drivebus.checks import validation_problems
from drivebus.errors import ConfigError

__all__ = ["LineSettings"]

_FORMAT = re.compile(r"^\s*(\d+)?[\s,/-]*([78])([NEO])([12])\s*$", re.IGNORECASE)


class LineSettings(BaseModel):
    """Baud rate and character format of a serial line (defaults: Modbus's 19200 8E1).

    Invalid settings raise ``ConfigError`` naming the field, the value and what is allowed.
    """

    model_config = ConfigDict(frozen=True, extra="forbid")

    baudrate: StrictInt = Field(19200, ge=300, le=4_000_000, description="bits per second")
    bytesize: Literal[7, 8] = 8
    parity: Literal["N", "E", "O"] = "E"
    stopbits: Literal[1, 2] = 1

    def __init__(self, **data: Any) -> None:
        try:
            super().__init__(**data)
        except ValidationError as exc:
            problems = "; ".join(validation_problems(exc, model=LineSettings))
            raise ConfigError(f"line settings: {problems}") from None

    @field_validator("bytesize", "stopbits", mode="before")
    @classmethod
    def _no_bool(cls, v: Any, info: ValidationInfo) -> Any:
        if isinstance(v, bool):
            allowed = "7 or 8" if info.field_name == "bytesize" else "1 or 2"
            raise ValueError(f"Input should be {allowed}")
        return v

    @classmethod
    def parse(cls, text: str, *, baudrate: int | None = None) -> LineSettings:
        """Parse "9600 8N1", "19200-8E1" or "8O1" (baud from ``baudrate``) into settings."""
        m = _FORMAT.match(text) if isinstance(text, str) else None
        if not m:
            raise ConfigError(
                f"line format {text!r} is not understood: expected e.g. '9600 8N1' or '8E1'"
            )
        baud = int(m.group(1)) if m.group(1) else baudrate
        if baud is None:
            raise ConfigError(f"line format {text!r} has no baud rate")
        try:
            return cls(
                baudrate=baud,
                bytesize=int(m.group(2)),  # type: ignore[arg-type]
                parity=m.group(3).upper(),  # type: ignore[arg-type]
                stopbits=int(m.group(4)),  # type: ignore[arg-type]
            )
        except ConfigError as exc:
            raise ConfigError(f"line format {text!r}: {exc}") from None

    @property
    def format(self) -> str:
        """The character format in the usual short form, e.g. ``8E1``."""
        return f"{self.bytesize}{self.parity}{self.stopbits}"

    def __str__(self) -> str:
        return f"{self.baudrate} {self.format}"
