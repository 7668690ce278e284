"""The machine commands of the ``drivebus`` command line, run in this process:
``status``, ``stop``, ``move``/``home``/``jog`` with a progress display, ``monitor``,
``check`` and ``sim`` (serving a machine's simulated drives).

Each opens the machine file's axes through ``drivebus.app.operations`` and renders them
(``drivebus.cli.views``); through a running ``drivebus serve`` the same commands are in
``drivebus.cli.remote``.
"""

from __future__ import annotations

import contextlib
import dataclasses
import json
import math
import sys
import time
from collections.abc import AsyncIterator, Awaitable, Callable, Sequence
from contextlib import asynccontextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import anyio
from rich.console import Group
from rich.live import Live
from rich.progress import BarColumn, Progress, SpinnerColumn, TextColumn, TimeElapsedColumn

from drivebus import errors
from drivebus.app.operations import (
    Operation,
    jog_ended_by_axis,
    opened,
    own_plan_refused,
    refuse_before_opening,
    run_operation,
)
from drivebus.app.operations import check_config as check_machine_file
from drivebus.app.snapshots import machine_snapshot
from drivebus.cli.remote import announce_sim_lines
from drivebus.cli.terminal import Out, explain, fmt_number
from drivebus.cli.views import axes_table, axis_line, axis_record, slaves_table, stats_lines
from drivebus.config import MachineConfig, load_config
from drivebus.errors import ArgumentError
from drivebus.motion import Axis, AxisState, Machine
from drivebus.text import count

__all__ = [
    "check_config",
    "check_goal",
    "check_jog_room",
    "home_axis",
    "jog_axis",
    "monitor",
    "move_axis",
    "refuse_early",
    "serve_sim",
    "show_status",
    "stop_axes",
]


# -- refusals before anything opens ------------------------------------------------------------


def refuse_early(config: Path | MachineConfig, axis: str, procedure: str, *,
                 target: float | None = None, speed: float | None = None,
                 speed_name: str = "--speed") -> MachineConfig:
    """The machine file, loaded, once the refusals it decides alone for ``procedure`` on
    ``axis`` have passed (``drivebus.app.operations.refuse_before_opening``): a refused
    command is an ``ArgumentError`` naming its argument (exit status 2) and opens nothing,
    so not one frame goes on the line. A ``ConfigError`` (an unknown axis) stays one."""
    cfg = config if isinstance(config, MachineConfig) else load_config(config)
    try:
        refuse_before_opening(cfg, axis, procedure, target=target, speed=speed)
    except errors.LimitViolation as exc:
        if target is not None and "target" in str(exc):
            raise ArgumentError(f"TARGET: {exc}") from None
        if speed is None:  # the machine file's speed and ramps, not an argument
            raise errors.ConfigError(f"axes.{axis}: {own_plan_refused(axis, exc)}"
                                     ) from None
        raise ArgumentError(f"{speed_name}: {exc}") from None
    except errors.NotSupported as exc:
        if isinstance(exc, errors.ConfigError):
            raise
        raise ArgumentError(f"AXIS: axis {axis}: {exc}") from None
    return cfg


def check_goal(ax: Axis, goal: float, name: str = "TARGET") -> None:
    """A goal beyond ``ax``'s soft limits refused as the bad argument ``name`` it is
    (``ArgumentError``, exit status 2), before anything is sent."""
    try:
        ax.check_limits(goal)
    except errors.LimitViolation as exc:
        raise ArgumentError(f"{name}: {exc}") from None


def check_jog_room(ax: Axis, speed: float, name: str = "SPEED") -> None:
    """No room before a soft limit in the jog's direction: the bad argument ``name``, as a
    move's target beyond it (``ArgumentError``, exit status 2)."""
    try:
        ax.envelope.check_jog_room(speed, ax.status)
    except errors.LimitViolation as exc:
        raise ArgumentError(f"{name}: {exc}") from None


# -- status, stop --------------------------------------------------------------------------------


async def show_status(out: Out, config: Path, axes: Sequence[str], as_json: bool) -> int:
    """Print the named axes' (or all axes') status, the unreachable ones Offline with the
    reason (also one line on stderr each); exit status 1 if any is in alarm or Offline."""
    async with opened(config, axes, observer=True) as m:  # looking must not stop anything
        if as_json:
            print(json.dumps([axis_record(m, n) for n in m.axes], indent=2), flush=True)
        elif out.interactive:
            out.console.print(axes_table(m))
        else:
            for n in m.axes:
                out.line(axis_line(m, n))
        for ax in m.axes.values():
            if ax.state is AxisState.OFFLINE and ax.error is not None:
                print(explain(ax.error)[0], file=sys.stderr, flush=True)
        faults = [n for n, a in m.axes.items() if a.state is AxisState.OFFLINE
                  or (a.status is not None and a.status.alarm)]
    return 1 if faults else 0


async def stop_axes(out: Out, config: Path, axes: Sequence[str]) -> int:
    """Stop the named axes (all if none), each with its decelerating stop."""
    records: list[dict[str, object]] = []
    async with opened(config, axes) as m:

        async def stop(name: str, ax: Axis) -> None:
            moving = ax.status is not None and ax.status.moving
            await ax.stop()
            what = "stopped" if moving else "at standstill"
            out.line(f"{name}: {what} at position={fmt_number(ax.position)} state={ax.state}")
            records.append({"axis": name, "was_moving": moving, "position": ax.position,
                            "state": str(ax.state)})

        async with anyio.create_task_group() as tg:
            for name, ax in m.axes.items():
                tg.start_soon(stop, name, ax)
    out.result(sorted(records, key=lambda r: str(r["axis"])))
    return 0


# -- motions with a progress display ---------------------------------------------------------------


async def _progress(out: Out, ax: Axis, what: str, start: float | None, goal: float | None) -> None:
    """Show ``ax`` moving until cancelled: a progress bar, or a line every 0.2 s."""
    if not out.interactive:
        last = 0.0
        async for _ in ax.watch():
            now = time.monotonic()
            if now - last >= 0.2:
                last = now
                print(f"{ax.name}: position={fmt_number(ax.position)} "
                      f"velocity={fmt_number(ax.velocity)} state={ax.state}", flush=True)
        return
    span = None if start is None or goal is None else abs(goal - start)
    with Progress(
        SpinnerColumn(), TextColumn("{task.description}"), BarColumn(),
        TextColumn("{task.fields[pos]}"), TimeElapsedColumn(), console=out.console,
    ) as prog:
        task = prog.add_task(what, total=span or None, pos="")
        async for _ in ax.watch():
            pos = ax.position
            done = None if span is None or pos is None or start is None else abs(pos - start)
            prog.update(task, completed=done, pos=f"{fmt_number(pos)} {ax.state}")


@dataclass
class _Run:
    """One axis operation on the terminal: the axis and the record of how it went."""

    axis: Axis
    op: Operation


@asynccontextmanager
async def _one_axis(out: Out, config: Path | MachineConfig, axis: str) -> AsyncIterator[_Run]:
    """Open the machine with just ``axis``; once it is closed again (every moving axis
    stopped and at standstill), report where an operation that did not complete left it."""
    run: _Run | None = None
    failure: BaseException | None = None
    try:
        async with opened(config, [axis]) as m:
            run = _Run(m.axes[axis], Operation(axis, ""))
            yield run
    except BaseException as exc:
        failure = exc
        raise
    finally:
        if run is not None and run.op.what and not run.op.done:
            ax, op = run.axis, run.op
            op.position, op.state = ax.position, str(ax.state)
            if ax.command_started_at >= op.started:  # the drive took a command: it moved
                out.line(f"{ax.name}: {op.what} stopped after "
                         f"{time.monotonic() - op.started:.2f} s, "
                         f"position={fmt_number(ax.position)} state={ax.state}")
            record = op.as_dict()
            if failure is not None:
                text, status = explain(failure)
                record["error"] = {"type": type(failure).__name__,
                                   "message": text.removeprefix("error: "),
                                   "exit_status": status}
            out.result(record)


async def _with_progress(
    out: Out, run: _Run, what: str, start: float | None, goal: float | None,
    motion: Callable[[], Awaitable[object]],
) -> None:
    """Run ``motion`` while showing its progress; a report line (``--json``: the record)
    when it completes."""
    ax, op = run.axis, run.op
    async with anyio.create_task_group() as tg:
        if not out.as_json:
            tg.start_soon(_progress, out, ax, what, start, goal)
        await run_operation(ax, what, motion, op)
        tg.cancel_scope.cancel()
    out.line(f"{ax.name}: {what} done in {op.seconds:.2f} s, "
             f"position={fmt_number(op.position)} state={op.state}")
    out.result(op.as_dict())


async def move_axis(
    out: Out, config: Path | MachineConfig, axis: str, target: float, by: bool, speed: float | None
) -> int:
    """Move one axis to ``target`` (or by it); Ctrl-C stops the axis before exiting."""
    async with _one_axis(out, config, axis) as run:
        ax = run.axis
        start = ax.position
        goal = (start or 0.0) + target if by else target
        what = f"move {'by' if by else 'to'} {target:g}"
        check_goal(ax, goal)  # a target beyond the soft limits is a bad argument

        async def motion() -> None:
            if by:
                await ax.move_by(target, speed=speed)
            else:
                await ax.move_to(target, speed=speed)

        await _with_progress(out, run, what, start, goal, motion)
    return 0


async def home_axis(out: Out, config: Path | MachineConfig, axis: str) -> int:
    """Run an axis's configured homing procedure."""
    async with _one_axis(out, config, axis) as run:
        ax = run.axis
        method = ax.config.homing.method or "the drive's default"
        await _with_progress(out, run, f"home ({method})", None, None, ax.home)
    return 0


async def jog_axis(out: Out, config: Path | MachineConfig, axis: str, speed: float,
                   seconds: float | None) -> int:
    """Jog an axis at ``speed`` units/s for ``seconds`` (until Ctrl-C without it)."""
    async with _one_axis(out, config, axis) as run:
        ax = run.axis
        check_jog_room(ax, speed)  # no room before a limit in its direction
        what = f"jog at {speed:g}/s" + (f" for {seconds:g} s" if seconds else " (Ctrl-C ends it)")

        async def motion() -> None:
            async with ax.jogging(speed):
                with anyio.move_on_after(seconds if seconds else math.inf):
                    async with contextlib.aclosing(ax.watch()) as statuses:
                        async for _ in statuses:  # the drive or a soft limit may end it
                            if jog_ended_by_axis(ax):
                                out.warn(f"axis {axis}: jog ended by the axis ({ax.state}"
                                         f"{f': {ax.error}' if ax.error else ''})")
                                return

        await _with_progress(out, run, what, None, None, motion)
    return 0


# -- monitor ---------------------------------------------------------------------------------------


async def monitor(out: Out, config: Path, interval: float, count: int | None) -> int:
    """Show every axis and the per-slave bus counters until Ctrl-C (or ``count`` updates);
    with ``--json`` one JSON line per update."""
    async with opened(config, observer=True) as m:
        n = 0
        if out.as_json:
            while count is None or n < count:
                snap = machine_snapshot(m).as_dict()
                out.result({"time": time.time(), "axes": [axis_record(m, n) for n in m.axes],
                            "lines": snap["lines"]}, indent=None)
                n += 1
                if count is None or n < count:
                    await anyio.sleep(interval)
            return 0
        if out.interactive:
            with Live(_monitor_view(m), console=out.console, refresh_per_second=8) as live:
                while count is None or n < count:
                    await anyio.sleep(interval)
                    live.update(_monitor_view(m))
                    n += 1
            return 0
        while count is None or n < count:
            stamp = time.strftime("%H:%M:%S")
            for name in m.axes:
                print(f"{stamp} {axis_line(m, name)}", flush=True)
            for text in stats_lines(m):
                print(f"{stamp} {text}", flush=True)
            n += 1
            if count is None or n < count:
                await anyio.sleep(interval)
    return 0


def _monitor_view(m: Machine) -> Group:
    return Group(axes_table(m), slaves_table(m))


# -- check ---------------------------------------------------------------------------------------


def check_config(out: Out, config: Path, sysfs: Path = Path("/sys"), *,
                 probe: bool = False) -> int:
    """Validate ``config`` and report on its lines (and, with ``probe``, on its drives);
    exit status 1 if a line or a drive cannot work."""
    from drivebus.app.commission import probe_axes

    report = check_machine_file(config, sysfs)
    probes = []
    if probe and not report.problems:
        announce_sim_lines(config)
        probes = anyio.run(probe_axes, config)
    problems = report.problems + [f"axis {p.axis}: {p.problem}" for p in probes if not p.ok]
    out.result({"file": str(config), "machine": report.name, "axes": report.axes,
                "lines": [dataclasses.asdict(ln) for ln in report.lines],
                "drives": [p.as_dict() for p in probes], "problems": problems})
    out.line(f"{config}: valid machine {report.name!r}: {count(report.axes, 'axis', 'axes')} "
             f"on {count(len(report.lines), 'line', 'lines')}")
    for ln in report.lines:
        on = ", ".join(ln.axes) or "no axes"
        if ln.simulated:
            out.line(f"line {ln.name}: simulated ({ln.where}, {ln.kind}): {on}")
        elif ln.kind == "serial":
            out.line(f"line {ln.name}: serial port {ln.where} at {ln.settings}: {on}")
            if ln.adapter is not None:
                out.line(f"line {ln.name}: {_adapter_text(ln.adapter)}")
        else:
            out.line(f"line {ln.name}: {ln.kind} {ln.where}: {on}")
        for w in ln.warnings:
            out.warn(f"line {ln.name}: {w}")
    for pr in probes:
        if pr.ok:
            out.line(f"axis {pr.axis}: {pr.family} answers at address {pr.address}"
                     f"{f' at {pr.settings}' if pr.settings else ''} ({pr.identity})")
    for p in problems:
        print(f"error: {p}", file=sys.stderr, flush=True)
    return 1 if problems else 0


def _adapter_text(a: dict[str, Any]) -> str:
    """One line about a port's adapter and what the line reaches with it."""
    parts = [f"adapter driver {a['driver'] or 'unknown'}"]
    timer = a["latency_timer_ms"]
    if timer is not None:
        parts.append(f"latency timer {timer} ms")
    parts.append("RS-485 mode on (RTS drives the transmitter)" if a["rs485_mode"]
                 else "RS-485 mode off (the adapter switches by itself)")
    parts.append("local echo expected" if a["local_echo"] else "no local echo")
    reach = (f"a 4-register poll is {a['poll_wire_ms']:.2f} ms on the wire: the line reaches "
             f"about {a['efficiency_low_latency']:.0%} of its capacity with a 1 ms timer")
    if timer is not None and timer > 1:
        reach += f", {a['efficiency_at_timer']:.0%} with {timer} ms"
    return "; ".join(parts) + "; " + reach


# -- the standalone simulator ---------------------------------------------------------------------


async def serve_sim(out: Out, config: Path, log: bool) -> int:
    """Serve the ``sim://`` lines of ``config`` (a twin per axis) until Ctrl-C/SIGTERM."""
    from drivebus.sim.serve import serve_simulators

    await serve_simulators(config, log=log, warn=out.warn)
    return 0
