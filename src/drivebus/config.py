"""Machine configuration: lines and axes, from TOML files, validated with pydantic.

A bad file gives one ``ConfigError`` naming the file, the key path and what is allowed.
Validation is complete before anything is opened: besides each value's type and range
(numbers finite everywhere), the cross-checks of ``MachineConfig`` run here, so that
``open_machine`` and ``drivebus check`` run exactly the same checks: two lines on one
port or simulator name, what each axis's drive accepts (``DriveProfile.axis_problems``:
address, line kind, line settings, pulses/rev, homing method, ``drive_options``), speeds
above ``max_speed``, and a simulation that cannot work (switches or soft limits that
leave the axis no room, positions beyond a drive's 32-bit range, unknown twin options).
"""

from __future__ import annotations

import math
import os
import re
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Annotated, Any, Literal
from urllib.parse import unquote, urlsplit

from pydantic import (
    BaseModel,
    ConfigDict,
    Field,
    PrivateAttr,
    StrictBool,
    StrictFloat,
    StrictInt,
    ValidationError,
    ValidationInfo,
    field_validator,
    model_validator,
)

from drivebus.checks import MAX_RETRIES, MAX_TIMEOUT, validation_problems
from drivebus.errors import ConfigError
from drivebus.providers import line_provider, scheme_of
from drivebus.settings import LineSettings

__all__ = [
    "NODE_PATTERN",
    "POSITION_NAME",
    "POSITION_NAME_RULE",
    "AxisConfig",
    "BrokerUrl",
    "HomingConfig",
    "LineConfig",
    "MachineConfig",
    "MqttConfig",
    "PollConfig",
    "is_position_name",
    "load_config",
    "machine_config",
    "parse_broker_url",
    "parse_config",
    "position_problems",
]


def _settings(v: Any) -> Any:
    if isinstance(v, str):
        return LineSettings.parse(v)
    return v


POSITION_NAME = r"^[A-Za-z_][A-Za-z0-9_-]{0,63}$"
"""A position's name: a TOML bare key (and one MQTT topic level)."""
POSITION_NAME_RULE = "a letter or _, then letters, digits, _ or - (64 at most)"
"""What ``POSITION_NAME`` asks of a position's name, in words."""


def is_position_name(name: object) -> bool:
    """Whether ``name`` may name a position (``POSITION_NAME``)."""
    return isinstance(name, str) and re.fullmatch(POSITION_NAME, name) is not None


def position_problems(config: MachineConfig, positions: Mapping[str, Any],
                      where: str = "positions") -> list[str]:
    """``key path: problem`` for each position that names an unknown axis, has a value
    that is not a finite number, or lies outside its axis's soft limits."""
    out: list[str] = []
    if not isinstance(positions, Mapping):
        return [f"{where}: expected tables of axis = position, not {positions!r}"]
    for name, values in positions.items():
        key = f"{where}.{name}"
        if not is_position_name(name):
            out.append(f"{key}: a position's name is {POSITION_NAME_RULE}")
            continue
        if name in config.axes:
            out.append(f"{key}: a position may not have an axis's name (drivebus move "
                       f"MACHINE {name} would be ambiguous)")
            continue
        if not isinstance(values, Mapping) or not values:
            out.append(f"{key}: expected a table of axis = position (at least one axis)")
            continue
        for axis, value in values.items():
            if axis not in config.axes:
                out.append(f"{key}.{axis}: no axis {axis!r} (axes: {', '.join(config.axes)})")
                continue
            if isinstance(value, bool) or not isinstance(value, int | float) or not (
                math.isfinite(value)
            ):
                out.append(f"{key}.{axis}: {value!r} is not a finite number")
                continue
            limits = config.axes[axis].limits
            if limits is not None and not limits[0] <= value <= limits[1]:
                out.append(f"{key}.{axis}: {value:g} is outside the soft limits "
                           f"{limits[0]:g}..{limits[1]:g}")
    return out


class _Model(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)



class LineConfig(_Model):
    """One line: a serial port (or ``sim://NAME``), Modbus TCP, or RTU over TCP."""

    kind: Literal["serial", "tcp", "rtu-over-tcp"] = "serial"
    port: str | None = Field(None, description="serial: device path or sim://NAME")
    host: str | None = Field(None, description="tcp: host name, address or sim://NAME")
    tcp_port: StrictInt = Field(502, ge=1, le=65535)
    settings: LineSettings = Field(default_factory=LineSettings)
    timeout: StrictFloat = Field(0.1, gt=0, le=MAX_TIMEOUT, description="response timeout, s")
    retries: StrictInt = Field(2, ge=0, le=MAX_RETRIES)
    local_echo: StrictBool = False
    rs485: StrictBool = False

    _parse_settings = field_validator("settings", mode="before")(_settings)

    @model_validator(mode="after")
    def _where(self) -> LineConfig:
        if self.kind == "serial" and not self.port:
            raise ValueError("a serial line needs 'port' (a device path or sim://NAME)")
        if self.kind != "serial" and not self.host:
            raise ValueError(f"a {self.kind} line needs 'host' (an address or sim://NAME)")
        unused = "host" if self.kind == "serial" else "port"
        if getattr(self, unused):
            raise ValueError(f"a {self.kind} line has no '{unused}' (set 'kind' to say what "
                             f"the line is: serial, tcp or rtu-over-tcp)")
        if self.simulated and not self.sim_name.strip("/"):
            raise ValueError("sim:// needs a name (sim://NAME)")
        return self

    @property
    def scheme(self) -> str | None:
        """The line provider's scheme when the line is ``SCHEME://NAME`` (``sim``), else None."""
        return scheme_of(self.port or self.host)

    @property
    def simulated(self) -> bool:
        """True if the line is the built-in simulator's (``sim://NAME``)."""
        return self.scheme == "sim"

    @property
    def sim_name(self) -> str:
        """The NAME of ``SCHEME://NAME[?OPTIONS]``."""
        address = self.port or self.host or ""
        return address.split("://", 1)[1].partition("?")[0] if "://" in address else ""

    @property
    def sim_options(self) -> dict[str, str]:
        """The OPTIONS of ``SCHEME://NAME?KEY=VALUE&...`` (the provider checks them)."""
        address = self.port or self.host or ""
        query = address.partition("?")[2]
        return dict(part.partition("=")[::2] for part in query.split("&") if part)


class HomingConfig(_Model):
    """How an axis homes: the profile's method name, speeds (units/s) and offset (units)."""

    method: str | None = None
    speed: StrictFloat = Field(10.0, gt=0)
    creep: StrictFloat = Field(2.0, gt=0)
    accel: StrictFloat = Field(100.0, gt=0)
    offset: StrictFloat = 0.0
    timeout: StrictFloat = Field(60.0, gt=0, le=3600)


class PollConfig(_Model):
    """Status poll periods in seconds: fast while moving or homing, slow at rest."""

    moving: StrictFloat = Field(0.02, gt=0, le=5)
    idle: StrictFloat = Field(0.2, gt=0, le=60)
    offline_after: StrictInt = Field(3, ge=1, le=100, description="failed polls before Offline")


class SimAxisConfig(_Model):
    """Simulation only: where the switches are (user units) and where the axis starts."""

    position: StrictFloat = 0.0
    home_switch: StrictFloat | None = None
    limit_negative: StrictFloat | None = None
    limit_positive: StrictFloat | None = None
    turnaround: StrictFloat = Field(0.001, ge=0, le=1)
    absent: StrictBool = False
    """No twin on the wire: the drive is configured but unplugged."""
    options: dict[str, Any] = Field(default_factory=dict)
    """Keyword options of the drive family's simulated twin (checked against it)."""

    @field_validator("options")
    @classmethod
    def _finite(cls, v: dict[str, Any]) -> dict[str, Any]:
        for key, value in v.items():
            if isinstance(value, float) and not math.isfinite(value):
                raise ValueError(f"{key}: {value!r} is not a finite number")
        return v


class AxisConfig(_Model):
    """One axis: which drive on which line, its units, defaults and limits."""

    line: str
    address: StrictInt = Field(ge=0, le=255, description="the slave address: 1..247 on "
                               "RS-485 and RTU over TCP, a unit id 0..255 on Modbus TCP")
    drive: str
    settings: LineSettings | None = None
    pulses_per_rev: StrictInt = Field(10000, gt=0)
    units_per_rev: StrictFloat = 1.0
    unit: str = Field("units", min_length=1, max_length=16, pattern=r"^[^\s]+$",
                      description="name of the user unit in messages and displays (mm, deg)")
    speed: StrictFloat = Field(10.0, gt=0, description="default speed, units/s")
    accel: StrictFloat = Field(100.0, gt=0, description="default acceleration, units/s²")
    decel: StrictFloat = Field(100.0, gt=0, description="default deceleration, units/s²")
    max_speed: StrictFloat | None = Field(None, gt=0)
    limits: tuple[StrictFloat, StrictFloat] | None = None
    in_position_tolerance: StrictInt = Field(2, ge=0, description="pulses")
    homing: HomingConfig = Field(default_factory=HomingConfig)
    poll: PollConfig = Field(default_factory=PollConfig)
    drive_options: dict[str, Any] = Field(default_factory=dict)
    io: dict[Annotated[str, Field(pattern=r"^[A-Za-z_][A-Za-z0-9_-]{0,63}$")], str] = Field(
        default_factory=dict,
        description="names for the drive's I/O terminals: vacuum = \"OUT1\"")
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
    def _known_drive(cls, v: str, info: ValidationInfo) -> str:
        """A family name, or a description file (relative to the machine file), as the
        family's canonical reference (see ``drivebus.drives.registry``)."""
        from drivebus.drives.registry import resolve_drive

        base = (info.context or {}).get("base")
        try:
            return resolve_drive(v, base)
        except ConfigError as exc:
            raise ValueError(str(exc)) from None

    @field_validator("limits")
    @classmethod
    def _ordered(cls, v: tuple[float, float] | None) -> tuple[float, float] | None:
        if v is not None and v[0] >= v[1]:
            raise ValueError(f"lower limit {v[0]} must be below upper limit {v[1]}")
        return v

    @model_validator(mode="after")
    def _drive_default_pulses(self) -> AxisConfig:
        """Without ``pulses_per_rev`` the axis takes its drive's own default (a
        description's ``[units.pulses_per_rev] default``): setup writes it to a drive
        with a microstep register, so a number of ours would have changed the drive."""
        if "pulses_per_rev" not in self.model_fields_set:
            from drivebus.drives.registry import family

            object.__setattr__(self, "pulses_per_rev", family(self.drive).default_pulses_per_rev)
        return self


NODE_PATTERN = r"^[A-Za-z0-9_-]{1,64}$"
"""A plant node's name: one MQTT topic level (no wildcards, no slash), usable by Home
Assistant discovery."""


@dataclass(frozen=True)
class BrokerUrl:
    """Where an MQTT broker is: ``mqtt://[user[:password]@]host[:port]``."""

    host: str
    port: int = 1883
    username: str | None = None
    password: str | None = None

    def __str__(self) -> str:
        return f"mqtt://{self.host}:{self.port}"


def parse_broker_url(url: object, *, error: type[ConfigError] = ConfigError) -> BrokerUrl:
    """``mqtt://[user[:password]@]host[:port]`` (port 1883 by default) as a ``BrokerUrl``;
    anything else is ``error`` naming the URL and the form expected."""
    form = "expected mqtt://HOST[:PORT] (e.g. mqtt://127.0.0.1:1883)"
    if not isinstance(url, str):
        raise error(f"broker URL: {form}, got {url!r}")
    parts = urlsplit(url.strip())
    if parts.scheme != "mqtt":
        raise error(f"broker URL {url!r}: the scheme must be mqtt:// ({form})")
    if parts.path not in ("", "/") or parts.query or parts.fragment:
        raise error(f"broker URL {url!r}: no path, query or fragment ({form})")
    try:
        port = parts.port
    except ValueError:
        raise error(f"broker URL {url!r}: the port must be a number 1..65535") from None
    if not parts.hostname:
        raise error(f"broker URL {url!r}: no host ({form})")
    if port == 0:
        raise error(f"broker URL {url!r}: the port must be a number 1..65535")
    return BrokerUrl(
        host=parts.hostname,
        port=port or 1883,
        username=None if parts.username is None else unquote(parts.username),
        password=None if parts.password is None else unquote(parts.password),
    )


class MqttConfig(_Model):
    """The ``[mqtt]`` section: the plant bridge of this machine (``drivebus.mqtt``)."""

    url: str | None = Field(None, description="broker, mqtt://HOST[:PORT]")
    node: Annotated[str, Field(pattern=NODE_PATTERN)] | None = Field(
        None, description="node name in the topics (default: the machine's name)")
    discovery: StrictBool = Field(True, description="publish Home Assistant discovery")
    state_rate: StrictFloat = Field(
        10.0, gt=0, le=1000, description="most axis state messages per axis per second")
    stats_period: StrictFloat = Field(
        5.0, gt=0, le=3600, description="seconds between line statistics messages")
    keepalive: StrictInt = Field(5, ge=1, le=3600, description="MQTT keepalive, s")
    reconnect_max: StrictFloat = Field(
        10.0, gt=0, le=600, description="longest wait between reconnection attempts, s")

    @field_validator("url")
    @classmethod
    def _url(cls, v: str | None) -> str | None:
        if v is not None:
            try:
                parse_broker_url(v)
            except ConfigError as exc:
                raise ValueError(str(exc)) from None
        return v


class MachineConfig(_Model):
    """A machine: named lines and named axes on them."""

    name: str = "machine"
    drives_path: list[str] = Field(
        default_factory=list,
        description="directories of drive descriptions (relative to the machine file)")
    lines: dict[str, LineConfig]
    axes: dict[Annotated[str, Field(pattern=r"^[A-Za-z_][A-Za-z0-9_-]*$")], AxisConfig]
    workers: Literal["auto"] | Annotated[StrictInt, Field(ge=0, le=64)] = 0
    """Worker processes that serve the lines (each its lines' schedulers and timing; the
    axes stay in this process): 0 none, N that many, "auto" by line count and cores."""
    mqtt: MqttConfig | None = None
    """The MQTT plant bridge's settings (used by ``python -m drivebus.mqtt`` and
    ``drivebus serve --mqtt``); None: no ``[mqtt]`` section."""
    positions: dict[str, dict[str, StrictFloat | StrictInt]] = Field(default_factory=dict)
    """Taught positions: name -> axis -> position in the axis's units
    (``drivebus.positions``)."""
    positions_file: str | None = Field(
        None, description="a TOML file beside the machine file that holds the [positions]")
    _source: Path | None = PrivateAttr(default=None)
    """The machine file it was read from (None: a mapping)."""

    @property
    def source(self) -> Path | None:
        """The machine file it was read from (None: given as a mapping)."""
        return self._source

    @model_validator(mode="before")
    @classmethod
    def _drives_path(cls, data: Any, info: ValidationInfo) -> Any:
        """Make ``drives_path``'s descriptions known before the axes name them."""
        from drivebus.drives.registry import add_drives_path

        paths = data.get("drives_path") if isinstance(data, dict) else None
        if isinstance(paths, list):
            base = Path((info.context or {}).get("base") or ".")
            for p in paths:
                if isinstance(p, str):
                    add_drives_path(base / Path(p).expanduser())
        return data

    @model_validator(mode="after")
    def _consistent(self) -> MachineConfig:
        problems = self._line_problems() + self._axis_problems()
        problems += position_problems(self, self.positions)
        if self.positions and self.positions_file is not None:
            problems.append("positions_file: the positions are either in [positions] or in "
                            "the positions file, not both")
        if problems:
            raise ValueError("; ".join(problems))
        return self

    def _line_problems(self) -> list[str]:
        """Two lines on one serial port (a device, a serial server's port) or one
        simulator name (serial and TCP alike)."""
        out = []
        seen: dict[tuple[str, str], str] = {}
        for name, ln in self.lines.items():
            if ln.simulated:
                key, where = ("sim", ln.sim_name.strip("/")), f"sim://{ln.sim_name}"
            elif ln.kind == "serial":
                assert ln.port is not None
                key, where = ("serial", os.path.realpath(ln.port)), f"serial port {ln.port}"
            elif ln.kind == "rtu-over-tcp":
                key = ("server", f"{ln.host}:{ln.tcp_port}")
                where = f"serial server {ln.host}:{ln.tcp_port}"
            else:
                continue  # a Modbus TCP server takes several connections
            if key in seen:
                field = "port" if ln.kind == "serial" else "host"
                out.append(f"lines.{name}.{field}: {where} is already line {seen[key]}: one "
                           f"line per port (put both lines' axes on one line)")
            else:
                seen[key] = name
        return out

    def _axis_problems(self) -> list[str]:
        from drivebus.drives.registry import family

        out = []
        seen: dict[tuple[str, int], str] = {}
        for name, ax in self.axes.items():
            where = f"axes.{name}"
            if ax.line not in self.lines:
                out.append(f"{where}.line: no line {ax.line!r} (lines: {', '.join(self.lines)})")
                continue
            key = (ax.line, ax.address)
            if key in seen:
                out.append(f"{where}.address: {ax.address} is already used by axis {seen[key]} "
                           f"on line {ax.line}")
            seen[key] = name
            line = self.lines[ax.line]
            if line.kind != "tcp" and not 1 <= ax.address <= 247:
                out.append(f"{where}.address: {ax.address} is outside 1..247 (an RTU "
                           f"address on {line.kind} line {ax.line}; a Modbus TCP unit id is "
                           f"0..255)")
                continue
            if line.kind == "tcp" and ax.settings is not None:
                out.append(f"{where}.settings: line {ax.line} is Modbus TCP: no serial settings")
            if line.kind == "rtu-over-tcp" and ax.settings not in (None, line.settings):
                out.append(f"{where}.settings: {ax.settings} differs from line {ax.line}'s "
                           f"{line.settings}: a serial server's port has one setting for all")
            profile = family(ax.drive).profile
            out += [f"{where}.{p}" for p in profile.axis_problems(
                address=ax.address,
                line_kind=line.kind,
                settings=None if line.kind == "tcp" else ax.settings or line.settings,
                pulses_per_rev=ax.pulses_per_rev,
                homing_method=ax.homing.method,
                options=ax.drive_options,
            )]
            out += [f"{where}.{p}" for p in _speed_problems(ax)]
            terminals = (*profile.io_inputs, *profile.io_outputs)
            out += [f"{where}.io.{alias}: the {ax.drive} drive has no terminal {t!r} (it has "
                    f"{', '.join(terminals) or 'none readable'})"
                    for alias, t in ax.io.items() if t not in terminals]
        for scheme in sorted({ln.scheme for ln in self.lines.values() if ln.scheme}):
            out += line_provider(scheme).problems(self)
        return out


def _speed_problems(ax: AxisConfig) -> list[str]:
    """Default speeds above ``max_speed``: every motion using them would be refused."""
    if ax.max_speed is None:
        return []
    speeds = {"speed": ax.speed, "homing.speed": ax.homing.speed, "homing.creep": ax.homing.creep}
    return [f"{key}: {v:g} units/s is above max_speed {ax.max_speed:g}"
            for key, v in speeds.items() if v > ax.max_speed]


def parse_config(
    data: dict[str, Any], source: str = "config", *, base: str | Path | None = None
) -> MachineConfig:
    """Validate a config mapping, cross-checks included; ``ConfigError`` names ``source``,
    each key path, the value and what is allowed. Description files an axis names
    (``drive = "drives/x.toml"``) are relative to ``base`` (the machine file's directory;
    by default the working directory)."""
    try:
        return MachineConfig.model_validate(data, context={"base": str(base or ".")})
    except ValidationError as exc:
        problems = "; ".join(validation_problems(exc, model=MachineConfig))
        raise ConfigError(f"{source}: {problems}") from None


def load_config(path: str | Path) -> MachineConfig:
    """Read and validate a TOML machine file."""
    if not isinstance(path, str | os.PathLike):
        raise ConfigError(f"a machine file is a path, not {path!r}")
    p = Path(path)
    from drivebus.drives.description import read_toml  # the descriptions' parser: on use

    config = parse_config(read_toml(p, "config file"), str(p), base=p.parent)
    config._source = p.resolve()
    return config


def machine_config(config: str | Path | Mapping[str, Any] | MachineConfig) -> MachineConfig:
    """A validated config from a machine file's path, a mapping or a ``MachineConfig``."""
    if isinstance(config, MachineConfig):
        return config
    if isinstance(config, Mapping):
        return parse_config(dict(config))
    return load_config(config)


async def machine_config_in_thread(
    config: str | Path | Mapping[str, Any] | MachineConfig,
) -> MachineConfig:
    """``machine_config`` from a coroutine: reading and validating a machine file parses
    the descriptions of the drives it names (tens of ms of CPU the first time), done in a
    worker thread so that no event-loop step holds a stop behind it (promise 1)."""
    if isinstance(config, MachineConfig):
        return config
    import anyio.to_thread

    return await anyio.to_thread.run_sync(machine_config, config)
