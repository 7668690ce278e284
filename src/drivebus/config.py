"""Machine configuration: lines and axes, from TOML files, validated with pydantic.

A bad file gives one ``ConfigError`` naming the file, the key path and what is allowed.
"""

from __future__ import annotations

import tomllib
from pathlib import Path
from typing import Annotated, Any, Literal

from pydantic import BaseModel, ConfigDict, Field, ValidationError, field_validator, model_validator

from drivebus.errors import ConfigError
from drivebus.settings import LineSettings

__all__ = ["AxisConfig", "HomingConfig", "LineConfig", "MachineConfig", "PollConfig", "load_config"]


def _settings(v: Any) -> Any:
    if isinstance(v, str):
        return LineSettings.parse(v)
    return v


class _Model(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)


class LineConfig(_Model):
    """One line: a serial port (or ``sim://NAME``), Modbus TCP, or RTU over TCP."""

    kind: Literal["serial", "tcp", "rtu-over-tcp"] = "serial"
    port: str | None = Field(None, description="serial: device path or sim://NAME")
    host: str | None = Field(None, description="tcp: host name, address or sim://NAME")
    tcp_port: int = Field(502, ge=1, le=65535)
    settings: LineSettings = Field(default_factory=LineSettings)
    timeout: float = Field(0.1, gt=0, le=10)
    retries: int = Field(2, ge=0, le=10)
    local_echo: bool = False
    rs485: bool = False

    _parse_settings = field_validator("settings", mode="before")(_settings)

    @model_validator(mode="after")
    def _where(self) -> LineConfig:
        if self.kind == "serial" and not self.port:
            raise ValueError("a serial line needs 'port' (a device path or sim://NAME)")
        if self.kind != "serial" and not self.host:
            raise ValueError(f"a {self.kind} line needs 'host' (an address or sim://NAME)")
        return self

    @property
    def simulated(self) -> bool:
        """True if the line is the built-in simulator's."""
        return (self.port or self.host or "").startswith("sim://")

    @property
    def sim_name(self) -> str:
        """The NAME of sim://NAME."""
        return (self.port or self.host or "").removeprefix("sim://")


class HomingConfig(_Model):
    """How an axis homes: the profile's method name, speeds (units/s) and offset (units)."""

    method: str | None = None
    speed: float = Field(10.0, gt=0)
    creep: float = Field(2.0, gt=0)
    accel: float = Field(100.0, gt=0)
    offset: float = 0.0
    timeout: float = Field(60.0, gt=0)


class PollConfig(_Model):
    """Status poll periods in seconds: fast while moving or homing, slow at rest."""

    moving: float = Field(0.02, gt=0, le=5)
    idle: float = Field(0.2, gt=0, le=60)
    offline_after: int = Field(3, ge=1, le=100, description="failed polls before Offline")


class SimAxisConfig(_Model):
    """Simulation only: where the switches are (user units) and where the axis starts."""

    position: float = 0.0
    home_switch: float | None = None
    limit_negative: float | None = None
    limit_positive: float | None = None
    turnaround: float = Field(0.001, ge=0, le=1)
    absent: bool = False
    """No twin on the wire: the drive is configured but unplugged."""
    options: dict[str, Any] = Field(default_factory=dict)


class AxisConfig(_Model):
    """One axis: which drive on which line, its units, defaults and limits."""

    line: str
    address: int = Field(ge=1, le=247)
    drive: str
    settings: LineSettings | None = None
    pulses_per_rev: int = Field(10000, gt=0)
    units_per_rev: float = 1.0
    speed: float = Field(10.0, gt=0, description="default speed, units/s")
    accel: float = Field(100.0, gt=0, description="default acceleration, units/s²")
    decel: float = Field(100.0, gt=0, description="default deceleration, units/s²")
    max_speed: float | None = Field(None, gt=0)
    limits: tuple[float, float] | None = None
    in_position_tolerance: int = Field(2, ge=0, description="pulses")
    homing: HomingConfig = Field(default_factory=HomingConfig)
    poll: PollConfig = Field(default_factory=PollConfig)
    drive_options: dict[str, Any] = Field(default_factory=dict)
    sim: SimAxisConfig = Field(default_factory=SimAxisConfig)

    _parse_settings = field_validator("settings", mode="before")(_settings)

    @field_validator("units_per_rev")
    @classmethod
    def _nonzero(cls, v: float) -> float:
        if v == 0:
            raise ValueError("must not be 0")
        return v

    @field_validator("drive")
    @classmethod
    def _known_drive(cls, v: str) -> str:
        from drivebus.drives.registry import family

        try:
            return family(v).name
        except ConfigError as exc:
            raise ValueError(str(exc)) from None

    @field_validator("limits")
    @classmethod
    def _ordered(cls, v: tuple[float, float] | None) -> tuple[float, float] | None:
        if v is not None and v[0] >= v[1]:
            raise ValueError(f"lower limit {v[0]} must be below upper limit {v[1]}")
        return v


class MachineConfig(_Model):
    """A machine: named lines and named axes on them."""

    name: str = "machine"
    lines: dict[str, LineConfig]
    axes: dict[Annotated[str, Field(pattern=r"^[A-Za-z_][A-Za-z0-9_-]*$")], AxisConfig]

    @model_validator(mode="after")
    def _consistent(self) -> MachineConfig:
        seen: dict[tuple[str, int], str] = {}
        for name, ax in self.axes.items():
            if ax.line not in self.lines:
                raise ValueError(
                    f"axes.{name}.line: no line {ax.line!r} (lines: {', '.join(self.lines)})"
                )
            key = (ax.line, ax.address)
            if key in seen:
                raise ValueError(
                    f"axes.{name}.address: {ax.address} is already used by axis {seen[key]} "
                    f"on line {ax.line}"
                )
            seen[key] = name
            line = self.lines[ax.line]
            if line.kind == "tcp" and ax.settings is not None:
                raise ValueError(f"axes.{name}.settings: line {ax.line} is Modbus TCP")
        return self


def _where(loc: tuple[int | str, ...]) -> str:
    return ".".join(str(p) for p in loc) or "(top level)"


def parse_config(data: dict[str, Any], source: str = "config") -> MachineConfig:
    """Validate a config mapping; ``ConfigError`` names ``source``, key path and the problem."""
    try:
        return MachineConfig.model_validate(data)
    except ValidationError as exc:
        problems = "; ".join(f"{_where(e['loc'])}: {e['msg']}" for e in exc.errors()[:5])
        raise ConfigError(f"{source}: {problems}") from None


def load_config(path: str | Path) -> MachineConfig:
    """Read and validate a TOML machine file."""
    p = Path(path)
    try:
        data = tomllib.loads(p.read_text())
    except FileNotFoundError:
        raise ConfigError(f"{p}: no such config file") from None
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(f"{p}: not valid TOML: {exc}") from None
    return parse_config(data, str(p))
