"""One-shot operations on a machine file: what the CLI's commands do, as plain coroutines.

Each opens only the axes it needs, returns results as data and raises typed errors; the
CLI renders them (``drivebus.cli.terminal``), a script may call them directly.
"""

from __future__ import annotations

import contextlib
import time
from collections.abc import AsyncIterator, Awaitable, Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import anyio

from drivebus.app.doctor import Adapter, check_serial_port, poll_efficiency
from drivebus.config import MachineConfig, load_config, machine_config_in_thread
from drivebus.drives.registry import drive_label
from drivebus.errors import ConfigError, DriveOffline, LimitViolation, NotSupported
from drivebus.motion import Axis, AxisState, Machine, open_machine
from drivebus.settings import LineSettings

__all__ = [
    "ConfigReport",
    "LineReport",
    "Operation",
    "check_config",
    "first_status",
    "jog_ended_by_axis",
    "opened",
    "refuse_before_opening",
    "run_operation",
    "subset",
]


def subset(cfg: MachineConfig, axes: Sequence[str]) -> MachineConfig:
    """``cfg`` with only the named axes and the lines they use (all if none are named)."""
    if not axes:
        return cfg
    missing = [a for a in axes if a not in cfg.axes]
    if missing:
        raise ConfigError(
            f"no axis {', '.join(missing)} in machine {cfg.name} (axes: {', '.join(cfg.axes)})"
        )
    chosen = {n: cfg.axes[n] for n in dict.fromkeys(axes)}
    used = {a.line for a in chosen.values()}
    lines = {n: ln for n, ln in cfg.lines.items() if n in used}
    return cfg.model_copy(update={"axes": chosen, "lines": lines})


def refuse_before_opening(
    cfg: MachineConfig, axis: str, procedure: str, *, target: float | None = None,
    speed: float | None = None,
) -> None:
    """Raise the refusal the machine file alone decides for ``procedure`` on ``axis``
    (``"move"``, ``"move_by"``, ``"jog"`` at the signed ``speed``, ``"home"``,
    ``"teach"``), before any port opens: an unknown axis (``ConfigError``), a drive that
    cannot do it (``NotSupported``; for ``"teach"``, a drive that cannot move to a
    position: ``ArgumentError``), an absolute ``target`` beyond the soft limits, a speed
    beyond ``max_speed`` or beyond what its drive runs (``LimitViolation``). The axis checks all of
    it again (and what needs its status) when the command runs; this only makes a refusal
    send nothing at all, not even the reads of opening."""
    from drivebus.bus import Bus
    from drivebus.drives.registry import family
    from drivebus.line import SerialLine
    from drivebus.motion.envelope import Envelope
    from drivebus.motion.machine import check_teachable
    from drivebus.motion.units import Units

    ac = subset(cfg, [axis]).axes[axis]
    fam = family(ac.drive)
    detached = Bus(SerialLine("/dev/null", LineSettings())).slave(  # never opened
        max(min(fam.profile.addresses), 1))
    try:
        profile = fam.profile(detached, pulses_per_rev=ac.pulses_per_rev, **ac.drive_options)
    except TypeError as exc:
        raise ConfigError(f"axes.{axis}.drive_options: {exc}") from None
    if procedure == "home":
        profile.check_supported("home")
        return
    if procedure == "teach":
        check_teachable(axis, profile)
        return
    envelope = Envelope(axis, ac, profile, Units(ac.pulses_per_rev, ac.units_per_rev))
    plan = envelope.plan(None if speed is None else abs(speed))
    if procedure == "jog":
        jog_speed = speed if speed is not None else plan.speed
        procedure = "move_absolute" if envelope.jog_bound(jog_speed) is not None \
            else "speed_run"
    elif procedure == "move":
        procedure = "move_absolute"
        if target is not None:
            envelope.check_limits(target)
    else:
        procedure = "move_relative"
    profile.check_supported(procedure)
    envelope.check_drive(plan)


async def first_status(m: Machine, timeout: float = 5.0) -> None:
    """Wait until every axis has a status from its actor; ``DriveOffline`` naming the silent
    ones after ``timeout`` s."""

    async def one(ax: Axis) -> None:
        if ax.status is not None or ax.state is AxisState.OFFLINE:
            return  # known: polled, or did not answer when the machine opened
        async with contextlib.aclosing(ax.watch()) as statuses:
            async for _ in statuses:
                return

    try:
        with anyio.fail_after(timeout):
            async with anyio.create_task_group() as tg:
                for ax in m.axes.values():
                    tg.start_soon(one, ax)
    except TimeoutError:
        silent = [n for n, a in m.axes.items() if a.status is None]
        raise DriveOffline(f"no status from axis {', '.join(silent)} within {timeout} s") from None


@contextlib.asynccontextmanager
async def opened(
    config: str | Path | MachineConfig, axes: Sequence[str] = (), *, observer: bool = False
) -> AsyncIterator[Machine]:
    """The machine with only ``axes`` (all if none) and their lines, every axis polled once.

    An ``observer`` (status, monitor) must not touch motion it did not start: leaving it
    stops only motions commanded through it; otherwise every moving axis is stopped. An
    observer also shows the axes whose drive does not answer (Offline, with the reason);
    an operation needs them all.
    """
    cfg = subset(await machine_config_in_thread(config), axes)  # descriptions: off the loop
    async with open_machine(cfg, stop_on_exit=not observer, require_all=not observer) as m:
        await first_status(m)
        yield m


@dataclass
class Operation:
    """One axis operation as it went: what, for how long, where it left the axis."""

    axis: str
    what: str
    started: float = 0.0
    """Monotonic time it began."""
    done: bool = False
    seconds: float = 0.0
    position: float | None = None
    state: str = ""

    def as_dict(self) -> dict[str, Any]:
        """JSON-ready data."""
        return {"axis": self.axis, "what": self.what, "done": self.done,
                "seconds": round(self.seconds, 4), "position": self.position,
                "state": self.state}


async def run_operation(
    axis: Axis, what: str, motion: Callable[[], Awaitable[object]],
    report: Operation | None = None,
) -> Operation:
    """Run ``motion`` on ``axis`` and fill ``report``: done or not, time, final position.

    The record is filled in also when the motion fails or is cancelled (``done`` False),
    so a caller can say where it left the axis.
    """
    op = report or Operation(axis.name, what)
    op.what, op.started = what, time.monotonic()
    try:
        await motion()
        op.done = True
    finally:
        op.seconds = time.monotonic() - op.started
        op.position, op.state = axis.position, str(axis.state)
    return op


def jog_ended_by_axis(axis: Axis) -> bool:
    """True when a jog that was running has ended on the axis's side (a limit, the drive)."""
    return axis.state is not AxisState.CONTINUOUS_MOTION


@dataclass
class LineReport:
    """One line of a machine file as ``check`` sees it."""

    name: str
    kind: str
    where: str
    settings: str | None
    simulated: bool
    axes: list[str]
    problems: list[str] = field(default_factory=list)
    warnings: list[str] = field(default_factory=list)
    adapter: dict[str, Any] | None = None
    """A real serial port's adapter: driver, latency timer, RS-485 mode, local echo, and
    the fraction of the line a 4-register poll can use with it."""


@dataclass
class ConfigReport:
    """What ``check`` found: the machine (valid, or ``load_config`` raised) and its lines."""

    name: str
    axes: int
    lines: list[LineReport]
    axis_problems: list[str] = field(default_factory=list)
    """Axes whose own speed and ramps their drive cannot run (each named)."""

    @property
    def problems(self) -> list[str]:
        """Every line's problems, named by line, then the axes'."""
        return [f"line {ln.name}: {p}" for ln in self.lines for p in ln.problems] + \
            self.axis_problems


def check_config(config: str | Path, sysfs: Path = Path("/sys")) -> ConfigReport:
    """Validate ``config`` exactly as ``open_machine`` does (``ConfigError`` if invalid), then
    look at its real serial ports (exists, permissions, adapter latency timer)."""
    cfg = load_config(config)
    lines = []
    for name, ln in cfg.lines.items():
        axes = [f"{n} ({drive_label(a.drive)} @{a.address})" for n, a in cfg.axes.items()
                if a.line == name]
        where = ln.port if ln.kind == "serial" else f"{ln.host}:{ln.tcp_port}"
        report = LineReport(
            name, ln.kind, ln.port or ln.host or "" if ln.scheme else where or "",
            None if ln.kind == "tcp" else str(ln.settings), ln.scheme is not None, axes,
        )
        if ln.scheme is None and ln.kind == "serial":
            assert ln.port is not None
            port = check_serial_port(ln.port, sysfs)
            report.problems, report.warnings = port.problems, port.warnings
            if port.adapter is not None:
                report.adapter = _adapter_record(port.adapter, ln.settings, ln.rs485,
                                                 ln.local_echo)
        lines.append(report)
    return ConfigReport(cfg.name, len(cfg.axes), lines, _plan_problems(cfg))


def _plan_problems(cfg: MachineConfig) -> list[str]:
    """The axes whose speed, accel and decel (the file's, or the defaults) their drive
    cannot run: every move without its own would be refused."""
    out = []
    for name in cfg.axes:
        try:
            refuse_before_opening(cfg, name, "move")
        except LimitViolation as exc:
            out.append(f"axis {name}: {own_plan_refused(name, exc)}")
        except NotSupported:
            continue  # an axis that does not move (monitoring): nothing to run
    return out


def own_plan_refused(axis: str, exc: LimitViolation) -> str:
    """What is wrong when ``axis``'s own speed and ramps (the machine file's, or the
    defaults) are what its drive refuses: no argument of a command, the file's."""
    why = str(exc).removeprefix(f"axis {axis}: ")
    return f"its speed, accel and decel (the machine file's, or the defaults): {why}"


def _adapter_record(adapter: Adapter, settings: LineSettings, rs485: bool, echo: bool
                    ) -> dict[str, Any]:
    """What ``check`` says about a port's adapter, as plain data."""
    lt = adapter.latency_timer_ms
    wire, best = poll_efficiency(settings, 0.0)
    record: dict[str, Any] = {
        "driver": adapter.driver, "latency_timer_ms": lt, "rs485_mode": rs485,
        "local_echo": echo, "poll_wire_ms": round(wire * 1e3, 3),
        "efficiency_low_latency": round(poll_efficiency(settings, 0.001)[1], 3),
        "efficiency_best": round(best, 3),
    }
    if lt is not None:
        record["efficiency_at_timer"] = round(poll_efficiency(settings, lt / 1000)[1], 3)
    return record
