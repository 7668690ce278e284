"""Snapshots: the machine, its lines and its axes as plain data.

The records every front end shows: the CLI's tables and JSON, the service's JSON and
WebSocket messages, the MQTT bridge's retained state. ``as_dict()`` gives JSON-ready data.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, fields
from typing import Any

from drivebus.bus import Bus
from drivebus.clock import monotonic
from drivebus.drives.status import DriveStatus
from drivebus.errors import DrivebusError
from drivebus.motion import Axis, Machine

__all__ = [
    "AxisSnapshot",
    "LineSnapshot",
    "MachineSnapshot",
    "axis_snapshot",
    "error_record",
    "line_snapshot",
    "machine_snapshot",
]


def _finite(v: float | None) -> float | None:
    """JSON has no NaN or infinity."""
    return v if v is None or math.isfinite(v) else None


def error_record(exc: BaseException | None) -> dict[str, str] | None:
    """A typed error as data: its type's name and its message."""
    if exc is None:
        return None
    return {"type": type(exc).__name__, "message": str(exc)}


def _copied(values: dict[str, Any]) -> dict[str, Any]:
    """``values`` with each dict among them copied: what ``dataclasses.asdict`` makes of
    a flat snapshot's data without its deep copy of every value (a fifth of the time,
    which counts for a machine of 128 axes: 16 ms in one step of the loop)."""
    return {k: dict(v) if isinstance(v, dict) else v for k, v in values.items()}


def _fields(snapshot: Any) -> dict[str, Any]:
    """A flat snapshot's fields by name, as ``_copied`` gives them."""
    return _copied({f.name: getattr(snapshot, f.name) for f in fields(snapshot)})


@dataclass(frozen=True)
class AxisSnapshot:
    """One axis as its actor last saw it, in user units."""

    name: str
    drive: str
    line: str
    address: int
    state: str
    position: float | None
    velocity: float | None
    enabled: bool | None
    moving: bool | None
    homed: bool
    alarm: bool
    alarm_code: int | None
    alarm_text: str
    limit_positive: bool
    limit_negative: bool
    soft_limits: tuple[float, float] | None
    target: float | None
    """The target of the motion under way, in user units (None: none)."""
    units: str
    """The axis's user unit (``mm``, ``deg``): positions, speeds/s, accelerations/s²."""
    units_per_rev: float
    pulses_per_rev: int
    error: dict[str, str] | None
    """What put the axis into ErrorStop or Offline (type and message)."""
    timestamp: float
    """When the status behind this was polled (monotonic seconds; 0 if never)."""
    inputs: dict[str, bool] = field(default_factory=dict)
    """The drive's inputs by name, as polled (the machine file's names too)."""
    outputs: dict[str, bool] = field(default_factory=dict)
    """The drive's outputs by name, as polled."""
    override: float = 1.0
    """The speed override the axis applies (its own times the machine's)."""
    queued: int = 0
    """Motions waiting in the axis's queue (buffered or blended)."""

    def as_dict(self) -> dict[str, Any]:
        """JSON-ready data."""
        d = _fields(self)
        d["soft_limits"] = list(self.soft_limits) if self.soft_limits else None
        return d


def axis_snapshot(
    axis: Axis, *, target_at: tuple[DriveStatus, float | None] | None = None
) -> AxisSnapshot:
    """``axis`` as plain data. ``target_at``: a status and the axis's target when that
    status came in (taken by a listener, as a recording takes it): while that status is
    still the axis's latest, the snapshot's target is that one, as its position and
    velocity are that poll's (a command given since shows with the next poll)."""
    st = axis.status
    cfg = axis.config
    target = axis.target if target_at is None or target_at[0] is not st else target_at[1]
    return AxisSnapshot(
        name=axis.name,
        drive=axis.profile.family,
        line=cfg.line,
        address=cfg.address,
        state=str(axis.state),
        position=_finite(axis.position),
        velocity=_finite(axis.velocity),
        enabled=None if st is None else st.enabled,
        moving=None if st is None else st.moving,
        homed=axis.homed,
        alarm=bool(st and st.alarm),
        alarm_code=None if st is None else st.alarm_code,
        alarm_text="" if st is None else st.alarm_text,
        limit_positive=bool(st and st.limit_positive),
        limit_negative=bool(st and st.limit_negative),
        soft_limits=cfg.limits,
        target=_finite(target),
        units=cfg.unit,
        units_per_rev=cfg.units_per_rev,
        pulses_per_rev=cfg.pulses_per_rev,
        error=error_record(axis.error),
        timestamp=0.0 if st is None else st.timestamp,
        inputs=axis.inputs,
        outputs=axis.outputs,
        override=axis.effective_override,
        queued=axis.queued,
    )


@dataclass(frozen=True)
class LineSnapshot:
    """One line: how it is set up and how busy it is."""

    name: str
    kind: str
    endpoint: str
    settings: str | None
    utilisation: float
    transactions: int
    errors: int
    retries: int
    timeouts: int
    last_error: str
    wire_time: float
    """Seconds the line carried frames since it opened: with ``timestamp``, a client
    gets the utilisation over any interval from two snapshots."""
    replies: int
    reply_time: float
    """Sum of reply latencies, seconds: over ``replies``, the mean latency."""
    timestamp: float
    """When this was taken (monotonic s, the clock of the axes' ``timestamp``)."""
    foreign_requests: int = 0
    """Requests of another master heard on the line (a fault: one master per line)."""
    foreign_master: str = ""
    """What the other master last sent, if any ("read holding registers ... from slave
    5"); empty while the line has one master."""
    slaves: dict[int, dict[str, Any]] = field(default_factory=dict)
    """Per-slave counters by address."""

    def as_dict(self) -> dict[str, Any]:
        """JSON-ready data."""
        d = _fields(self)
        d["slaves"] = {str(k): _copied(slave) for k, slave in self.slaves.items()}
        return d


def line_snapshot(name: str, bus: Bus, kind: str, endpoint: str) -> LineSnapshot:
    """The line ``name`` served by ``bus`` as plain data."""
    stats = bus.stats
    total = stats.total()
    last = next((s.last_error for s in stats.slaves.values() if s.last_error), "")
    return LineSnapshot(
        name=name,
        kind=kind,
        endpoint=endpoint,
        settings=None if bus.line.settings is None else str(bus.line.settings),
        utilisation=round(stats.utilisation, 4),
        transactions=stats.transactions,
        errors=total.errors,
        retries=total.retries,
        timeouts=total.timeouts,
        last_error=last,
        wire_time=stats.wire_time,
        replies=stats.replies,
        reply_time=stats.reply_time,
        timestamp=monotonic(),
        foreign_requests=stats.foreign_requests,
        foreign_master=stats.foreign_last,
        slaves={a: s.as_dict() for a, s in sorted(stats.slaves.items())},
    )


@dataclass(frozen=True)
class MachineSnapshot:
    """The whole machine: its name, lines and axes."""

    name: str
    lines: list[LineSnapshot]
    axes: list[AxisSnapshot]
    override: float = 1.0
    """The machine's speed override."""
    positions: dict[str, dict[str, float]] = field(default_factory=dict)
    """The taught positions."""

    def as_dict(self) -> dict[str, Any]:
        """JSON-ready data."""
        return {
            "name": self.name,
            "lines": [ln.as_dict() for ln in self.lines],
            "axes": [ax.as_dict() for ax in self.axes],
            "override": self.override,
            "positions": self.positions,
        }


def machine_snapshot(machine: Machine) -> MachineSnapshot:
    """``machine`` as plain data."""
    lines = []
    for name, bus in machine.buses.items():
        cfg = machine.config.lines[name]
        endpoint = cfg.port or f"{cfg.host}:{cfg.tcp_port}"
        lines.append(line_snapshot(name, bus, cfg.kind, endpoint))
    return MachineSnapshot(
        machine.config.name, lines, [axis_snapshot(a) for a in machine.axes.values()],
        machine.override, machine.positions,
    )


def describe(exc: DrivebusError) -> str:
    """One line naming a typed error (for logs and terminals)."""
    return f"{type(exc).__name__}: {exc}"
