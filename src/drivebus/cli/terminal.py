"""The terminal side of the ``drivebus`` commands: output, signals and progress displays.

The commands' work is done by the application layer (``drivebus.app``: operations, scan,
the doctor) and the simulator's server (``drivebus.sim.serve``); this module renders it.
Output goes through ``Out``: rich progress and live views on a terminal, plain lines (one
event per line, ``key=value`` fields) when stdout is a pipe or a file. ``run_guarded``
runs a command so that SIGINT/SIGTERM cancel it, its cleanup (stopping axes) included.
"""

from __future__ import annotations

import contextlib
import dataclasses
import errno
import functools
import json
import logging
import math
import os
import re
import signal
import sys
import termios
import time
from collections.abc import AsyncIterator, Awaitable, Callable, Sequence
from contextlib import asynccontextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import anyio
import anyio.to_thread
from rich.console import Console, Group
from rich.live import Live
from rich.progress import (
    BarColumn,
    MofNCompleteColumn,
    Progress,
    SpinnerColumn,
    TextColumn,
    TimeElapsedColumn,
)

from drivebus import errors
from drivebus.app import registers
from drivebus.app.lifecycle import run_until_signalled
from drivebus.app.operations import (
    Operation,
    jog_ended_by_axis,
    opened,
    run_operation,
)
from drivebus.app.operations import (
    check_config as check_machine_file,
)
from drivebus.app.registers import RegisterValues, open_slave
from drivebus.app.scan import Found, scan
from drivebus.app.snapshots import machine_snapshot
from drivebus.cli.views import axes_table, axis_line, axis_record, slaves_table, stats_lines
from drivebus.errors import (
    ArgumentError,
    ConfigError,
    DrivebusError,
    DriveOffline,
    LineClosed,
    TransactionError,
)
from drivebus.motion import Axis, AxisState, Machine
from drivebus.service.client import ServiceClient
from drivebus.settings import LineSettings
from drivebus.sim.serve import serve_simulators

__all__ = [
    "Out",
    "announce_sim_lines",
    "check_config",
    "found_line",
    "home_axis",
    "jog_axis",
    "monitor",
    "move_axis",
    "run_guarded",
    "scan_line",
    "serve_sim",
    "service_owner",
    "show_status",
    "stop_axes",
]


def configure_logging(level: str, *, trace: bool = False) -> None:
    """Log to stderr at ``level`` (``debug``..``error``); ``trace`` also logs every frame
    (the ``drivebus.trace`` logger) whatever the level."""
    handler = logging.StreamHandler(sys.stderr)
    handler.setFormatter(logging.Formatter("%(levelname)s %(name)s: %(message)s"))
    root = logging.getLogger("drivebus")
    root.handlers[:] = [handler]
    root.setLevel(level.upper())
    root.propagate = False
    logging.getLogger("drivebus.trace").setLevel(logging.DEBUG if trace else logging.WARNING)
    if trace and root.level > logging.DEBUG:
        root.setLevel(logging.DEBUG)
        for name in ("drivebus.motion", "drivebus.app", "drivebus.bus", "drivebus.line",
                     "drivebus.sim", "drivebus.drives"):
            logging.getLogger(name).setLevel(level.upper())


class Out:
    """Where command output goes: a rich console on a terminal, plain lines otherwise."""

    def __init__(self, interactive: bool | None = None, *, as_json: bool = False) -> None:
        self.as_json = as_json
        """Results as JSON on stdout (``--json``): no tables, no progress, no text lines."""
        self.interactive = (sys.stdout.isatty() if interactive is None else interactive) and (
            not as_json)
        self.console = Console(highlight=False)

    def line(self, text: str) -> None:
        """One line of output (none with ``--json``)."""
        if self.as_json:
            return
        if self.interactive:
            self.console.print(text, markup=False)
        else:
            print(text, flush=True)

    results: int = 0
    """Results printed as JSON in this process (a failure then adds no JSON of its own)."""

    def result(self, data: object, *, indent: int | None = 2) -> None:
        """A command's result as JSON (with ``--json``; one line when ``indent`` is None)."""
        if self.as_json:
            print(json.dumps(data, indent=indent), flush=True)
            Out.results += 1

    def warn(self, text: str) -> None:
        """A warning on stderr."""
        print(f"warning: {text}", file=sys.stderr, flush=True)


# -- running under a signal guard ----------------------------------------------------------------


def run_guarded(fn: Callable[[], Awaitable[int]], *, interrupt_ok: bool = False) -> int:
    """Run a command: SIGINT/SIGTERM cancel it (its cleanup, e.g. stopping moving axes,
    runs in full) and give exit status 128+signal, or 0 if ``interrupt_ok`` (commands that
    run until Ctrl-C); an interrupted command says so on stderr."""

    def said(sig: signal.Signals) -> None:
        if not interrupt_ok:
            print(f"interrupted ({sig.name})", file=sys.stderr, flush=True)

    return run_until_signalled(fn, interrupt_ok=interrupt_ok, on_signal=said)


def _fmt(v: float | None) -> str:
    return "-" if v is None else f"{v:.3f}"


# -- scan ----------------------------------------------------------------------------------------


def found_line(f: Found) -> str:
    """One slave found by a scan, as a line."""
    detail = f" ({f.detail})" if f.detail else ""
    where = f"unit {f.address}" if f.settings is None else f"address {f.address} at {f.settings}"
    return f"{where}: {f.family}{detail}"


async def scan_line(
    out: Out, port: str, settings: list[LineSettings], addresses: list[int], timeout: float,
    *, quiet: bool = False,
) -> list[Found]:
    """Scan ``port`` (any target) with a progress bar (terminal) or a line per slave found."""
    if quiet or not out.interactive:

        def report(a: int, s: LineSettings | None, hit: Found | None) -> None:
            if hit is not None and not quiet:
                print(f"found {found_line(hit)}", flush=True)

        return await scan(port, settings, addresses, timeout=timeout, on_probe=report)
    with Progress(TextColumn("{task.description}"), BarColumn(), MofNCompleteColumn(),
                  console=out.console) as prog:
        rounds = len(settings) if settings else 1
        task = prog.add_task("scanning", total=rounds * len(addresses))

        def show(a: int, s: LineSettings | None, hit: Found | None) -> None:
            extra = 0
            if hit is not None:
                if s is not None:
                    extra = len(settings) - settings.index(s) - 1  # not probed again
                prog.console.print(f"found {found_line(hit)}", markup=False)
            where = "unit" if s is None else f"{s} address"
            prog.update(task, advance=1 + extra, description=f"scanning {where} {a:>3}")

        return await scan(port, settings, addresses, timeout=timeout, on_probe=show)


# -- register tools ------------------------------------------------------------------------------


async def read_registers(
    out: Out, target: str, address: int, register: int, count: int, input_table: bool,
    settings: object, fmt: str, interval: float | None, polls: int | None, timeout: float,
) -> int:
    """Read registers once, or every ``interval`` s (``polls`` times, else until Ctrl-C)."""
    assert settings is None or isinstance(settings, LineSettings)
    async with open_slave(target, address, settings=settings, timeout=timeout) as slave:

        async def read() -> RegisterValues:
            words, values = await registers.read_registers(
                slave, register, count, input=input_table, fmt=fmt)
            return RegisterValues(target, address, register, input_table, words, fmt, values)

        return await _poll_registers(out, read, interval, polls)


async def _poll_registers(
    out: Out, read: Callable[[], Awaitable[RegisterValues]], interval: float | None,
    polls: int | None,
) -> int:
    """Print what ``read`` returns once, or every ``interval`` s (``polls`` times, else
    until Ctrl-C); exit status 0."""
    n = 0
    while True:
        record = await read()
        if out.as_json:
            out.result(record.as_dict(), indent=None if interval else 2)
        else:
            step = registers.words_per_value(record.format)
            stamp = f"{time.strftime('%H:%M:%S')} " if interval else ""
            for i, v in enumerate(record.values):
                out.line(f"{stamp}[{record.register + i * step}]: {v}")
        n += 1
        if interval is None or (polls is not None and n >= polls):
            return 0
        await anyio.sleep(interval)


async def write_registers(
    out: Out, target: str, address: int, register: int, values: Sequence[str],
    settings: object, fmt: str, timeout: float,
) -> int:
    """Write registers and say what went to the slave."""
    assert settings is None or isinstance(settings, LineSettings)
    async with open_slave(target, address, settings=settings, timeout=timeout,
                          broadcast=True) as slave:
        words = await registers.write_registers(slave, register, values, fmt=fmt)
    whom = "every slave (broadcast, no reply)" if address == 0 else f"slave {address}"
    out.line(f"wrote {len(words)} register{'' if len(words) == 1 else 's'} from "
             f"[{register}] of {whom} on {target}: "
             f"{' '.join(f'0x{w:04X}' for w in words)}")
    out.result({"target": target, "address": address, "register": register,
                "format": fmt, "words": words})
    return 0


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
            out.line(f"{name}: {what} at position={_fmt(ax.position)} state={ax.state}")
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
                print(f"{ax.name}: position={_fmt(ax.position)} velocity={_fmt(ax.velocity)} "
                      f"state={ax.state}", flush=True)
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
            prog.update(task, completed=done, pos=f"{_fmt(pos)} {ax.state}")


@dataclass
class _Run:
    """One axis operation on the terminal: the axis and the record of how it went."""

    axis: Axis
    op: Operation


@asynccontextmanager
async def _one_axis(out: Out, config: Path, axis: str) -> AsyncIterator[_Run]:
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
                         f"position={_fmt(ax.position)} state={ax.state}")
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
             f"position={_fmt(op.position)} state={op.state}")
    out.result(op.as_dict())


async def move_axis(
    out: Out, config: Path, axis: str, target: float, by: bool, speed: float | None
) -> int:
    """Move one axis to ``target`` (or by it); Ctrl-C stops the axis before exiting."""
    async with _one_axis(out, config, axis) as run:
        ax = run.axis
        start = ax.position
        goal = (start or 0.0) + target if by else target
        what = f"move {'by' if by else 'to'} {target:g}"
        try:
            ax.check_limits(goal)  # a target beyond the soft limits is a bad argument
        except errors.LimitViolation as exc:
            raise ArgumentError(f"TARGET: {exc}") from None

        async def motion() -> None:
            if by:
                await ax.move_by(target, speed=speed)
            else:
                await ax.move_to(target, speed=speed)

        await _with_progress(out, run, what, start, goal, motion)
    return 0


async def home_axis(out: Out, config: Path, axis: str) -> int:
    """Run an axis's configured homing procedure."""
    async with _one_axis(out, config, axis) as run:
        ax = run.axis
        method = ax.config.homing.method or "the drive's default"
        await _with_progress(out, run, f"home ({method})", None, None, ax.home)
    return 0


async def jog_axis(out: Out, config: Path, axis: str, speed: float, seconds: float | None) -> int:
    """Jog an axis at ``speed`` units/s for ``seconds`` (until Ctrl-C without it)."""
    async with _one_axis(out, config, axis) as run:
        ax = run.axis
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


# -- errors as one line ----------------------------------------------------------------------------

_MISSING = "the port does not exist: plug in the adapter, check the name (ls /dev/serial/by-id/)"
_DENIED = ("add your user to the port's group (sudo usermod -aG dialout $USER) and log in "
           "again")
_PORT_HINTS = {
    errno.ENOENT: _MISSING,
    errno.ENODEV: _MISSING,
    errno.ENXIO: _MISSING,
    errno.EACCES: _DENIED,
    errno.EPERM: _DENIED,
    errno.EBUSY: "another program has the port open: close it (fuser -v PORT shows which)",
}


def _errno(exc: BaseException) -> int | None:
    seen: BaseException | None = exc
    while seen is not None:
        code = getattr(seen, "errno", None)
        if isinstance(code, int):
            return code
        seen = seen.__cause__ or seen.__context__
    return None


def explain(exc: BaseException) -> tuple[str, int]:
    """The one line to print for ``exc`` (cause; what to do) and the exit status."""
    if isinstance(exc, ConfigError | ArgumentError):
        return f"error: {exc}", 2
    code = _errno(exc)
    if isinstance(exc, LineClosed | OSError) and code in _PORT_HINTS:
        port = getattr(exc, "filename", None)
        if port is None and (m := re.search(r"serial port '([^']+)'", str(exc))):
            port = m.group(1)
        return f"error: cannot open {port or 'the port'}: {os.strerror(code)}; " \
               f"{_PORT_HINTS[code]}", 1
    if isinstance(exc, errors.ModbusException):
        return (f"error: {exc}; the slave answered, refusing the request: check the register "
                f"address, count and value against the drive's manual"), 1
    if isinstance(exc, errors.PartialWrite):
        return f"error: {exc}", 1
    if isinstance(exc, DriveOffline | TransactionError):
        return (f"error: {exc}; check power, wiring, address and line settings "
                f"(`drivebus scan PORT` lists the slaves that answer)"), 1
    if isinstance(exc, termios.error):
        return f"error: the serial port refused the line settings: {exc.args[-1]}", 1
    return f"error: {exc}", 1


# -- the standalone simulator ---------------------------------------------------------------------


async def serve_sim(out: Out, config: Path, log: bool) -> int:
    """Serve the ``sim://`` lines of ``config`` (a twin per axis) until Ctrl-C/SIGTERM."""
    await serve_simulators(config, log=log, warn=out.warn)
    return 0


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
    out.line(f"{config}: valid machine {report.name!r}: {_count(report.axes, 'axis', 'axes')} "
             f"on {_count(len(report.lines), 'line', 'lines')}")
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


def _count(n: int, one: str, many: str) -> str:
    return f"{n} {one if n == 1 else many}"


# -- through a running drivebus serve (the line's one owner) ---------------------------------------


def announce_sim_lines(config: Path) -> None:
    """Say on stderr, for each ``sim://`` line of ``config``, whether opening the machine
    here reaches a running ``drivebus sim`` (always) or starts a private simulator (on a
    terminal; logged at INFO otherwise, which ``-v`` shows)."""
    from drivebus.config import load_config
    from drivebus.sim.serve import published

    try:
        cfg = load_config(config)
    except ConfigError:
        return  # the command itself says what is wrong with the file
    for ln in cfg.lines.values():
        if not ln.simulated:
            continue
        found = published(ln.sim_name)
        where = ln.port or ln.host
        if found is not None:
            print(f"note: {where}: reaching the running drivebus sim on {found.where}",
                  file=sys.stderr, flush=True)
            continue
        note = (f"{where}: no drivebus sim serves it: starting a private simulator (its "
                f"drives start afresh; `drivebus sim CONFIG` keeps them between commands)")
        if sys.stderr.isatty():  # at a terminal; scripts and pipes see it with -v
            print(f"note: {note}", file=sys.stderr, flush=True)
        else:
            logging.getLogger("drivebus.sim").info(note)


def service_owner(
    config: Path, server: str | None, token: str | None, local: bool
) -> ServiceClient | None:
    """The ``drivebus serve`` that owns ``config``'s machine (``--server``, or found
    through the file), as a client; None to open the machine here."""
    from drivebus.service.client import find_service

    url = None if local else server or find_service(config)
    if url is None:
        announce_sim_lines(config)
        return None
    if server is None:
        print(f"note: {config} is served by a running drivebus serve at {url}: talking to "
              f"it (--local opens the machine here)", file=sys.stderr, flush=True)
    return ServiceClient(url, token=token)


async def _call(fn: Callable[..., Any], *args: Any) -> Any:
    """A blocking client request, off the event loop."""
    return await anyio.to_thread.run_sync(functools.partial(fn, *args))


def _remote_line(a: dict[str, Any]) -> str:
    flags = [k for k in ("enabled", "moving", "homed", "limit_negative", "limit_positive")
             if a.get(k)]
    extra = ""
    if a.get("alarm"):
        extra = f" alarm={a.get('alarm_code')} {a.get('alarm_text', '')}".rstrip()
    elif a.get("error"):
        extra = f" error={a['error'].get('message')!r}"
    return (f"{a['name']}: {a['drive']} line={a['line']} address={a['address']} "
            f"state={a['state']} position={_fmt(a.get('position'))} "
            f"velocity={_fmt(a.get('velocity'))} flags={','.join(flags) or '-'}{extra}")


async def remote_status(out: Out, client: ServiceClient, axes: Sequence[str], as_json: bool
                        ) -> int:
    """``status`` through the service: every axis (or the named ones) as it polls them."""
    machine = await _call(client.machine)
    names = list(axes) or [a["name"] for a in machine["axes"]]
    records = [await _call(client.axis, n) for n in names]
    if as_json:
        print(json.dumps([{"axis": r["name"], **r} for r in records], indent=2), flush=True)
    else:
        for r in records:
            out.line(_remote_line(r))
    faults = [r for r in records if r["state"] == "Offline" or r.get("alarm")]
    return 1 if faults else 0


async def remote_motion(out: Out, client: ServiceClient, axis: str, what: str, path: str,
                        body: object = None) -> int:
    """Start a motion on the service and wait for it; cancelled (Ctrl-C), cancel it.
    ``axis`` is the axis shown while it runs ("": the motion's own axes, not shown)."""
    record = await _call(client.start, path, body)
    started = shown = time.monotonic()
    axis = axis or ",".join(record.get("axes") or [])
    try:
        while record.get("state") == "running":
            await anyio.sleep(0.05)
            record = await _call(client.request, "GET", f"/motions/{record['id']}")
            if time.monotonic() - shown >= 0.2 and record.get("state") == "running" and (
                "," not in axis
            ):
                shown = time.monotonic()
                a = await _call(client.axis, axis)
                out.line(f"{axis}: position={_fmt(a.get('position'))} "
                         f"velocity={_fmt(a.get('velocity'))} state={a['state']}")
    except BaseException:
        with anyio.CancelScope(shield=True):
            record = await _call(client.cancel, record["id"])
            for name in axis.split(","):
                a = await _call(client.axis, name)
                out.line(f"{name}: {what} stopped after {time.monotonic() - started:.2f} s, "
                         f"position={_fmt(a.get('position'))} state={a['state']}")
        raise
    seen = {name: await _call(client.axis, name) for name in axis.split(",")}
    a = next(iter(seen.values()))
    op = {"axis": axis, "what": what, "done": record["state"] == "done",
          "seconds": round(time.monotonic() - started, 4), "position": a.get("position"),
          "state": a["state"], "motion": record}
    if record["state"] != "done":
        err = record.get("error") or {}
        kind = getattr(errors, str(err.get("type")), DrivebusError)
        raise kind(str(err.get("message", f"the {what} ended {record['state']}")))
    for name, a in seen.items():
        out.line(f"{name}: {what} done in {op['seconds']:.2f} s, "
                 f"position={_fmt(a.get('position'))} state={a['state']}")
    out.result(op)
    return 0


async def remote_jog(out: Out, client: ServiceClient, axis: str, speed: float,
                     seconds: float | None) -> int:
    """Jog through the service, fed every 0.2 s (a 0.5 s watchdog); stop at the end."""
    started = time.monotonic()
    try:
        with anyio.move_on_after(seconds if seconds else math.inf):
            while True:
                await _call(client.command, axis, "jog", {"speed": speed, "ttl": 0.5})
                await anyio.sleep(0.2)
    finally:
        with anyio.CancelScope(shield=True):
            await _call(client.command, axis, "stop")
            a = await _call(client.axis, axis)
            out.line(f"{axis}: jog at {speed:g}/s ended after "
                     f"{time.monotonic() - started:.2f} s, position={_fmt(a.get('position'))} "
                     f"state={a['state']}")
            out.result({"axis": axis, "what": f"jog at {speed:g}", "done": True,
                        "position": a.get("position"), "state": a["state"]})
    return 0


async def remote_stop(out: Out, client: ServiceClient, axes: Sequence[str]) -> int:
    """``stop`` through the service."""
    machine = await _call(client.machine)
    names = list(axes) or [a["name"] for a in machine["axes"]]
    records = []
    for n in names:
        await _call(client.command, n, "stop")
        a = await _call(client.axis, n)
        out.line(f"{n}: at standstill at position={_fmt(a.get('position'))} "
                 f"state={a['state']}")
        records.append({"axis": n, "position": a.get("position"), "state": a["state"]})
    out.result(records)
    return 0


async def remote_monitor(out: Out, client: ServiceClient, interval: float,
                         count: int | None) -> int:
    """``monitor`` through the service: its axes every ``interval`` s."""
    n = 0
    while count is None or n < count:
        machine = await _call(client.machine)
        records = [await _call(client.axis, a["name"]) for a in machine["axes"]]
        if out.as_json:
            out.result({"time": time.time(), "axes": records, "lines": machine["lines"]},
                       indent=None)
        else:
            stamp = time.strftime("%H:%M:%S")
            for r in records:
                out.line(f"{stamp} {_remote_line(r)}")
        n += 1
        if count is None or n < count:
            await anyio.sleep(interval)
    return 0


async def remote_read(
    out: Out, client: ServiceClient, line: str, address: int, register: int, count: int,
    input_table: bool, fmt: str, interval: float | None, polls: int | None,
) -> int:
    """``read`` through the service's bus (line ``line``), once or every ``interval`` s."""
    words_needed = count * registers.words_per_value(fmt)

    async def read() -> RegisterValues:
        words = await _call(functools.partial(client.read, line, address, register,
                                              words_needed, input=input_table))
        return RegisterValues(f"{client.url} line {line}", address, register, input_table,
                              words, fmt, registers.decode(words, fmt))

    return await _poll_registers(out, read, interval, polls)


async def remote_write(out: Out, client: ServiceClient, line: str, address: int,
                       register: int, words: list[int]) -> int:
    """``write`` through the service's bus (line ``line``)."""
    await _call(client.write, line, address, register, words)
    out.line(f"wrote {len(words)} register{'' if len(words) == 1 else 's'} from "
             f"[{register}] of slave {address} on line {line} of {client.url}: "
             f"{' '.join(f'0x{w:04X}' for w in words)}")
    out.result({"target": f"{client.url} line {line}", "address": address,
                "register": register, "words": words})
    return 0
