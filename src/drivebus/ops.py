"""What the ``drivebus`` commands do, as coroutines: one-shot axis operations, the live
monitor, the standalone simulator and the config check. ``drivebus.cli`` parses the
arguments, runs these under a SIGINT/SIGTERM guard and turns errors into one line.

Output goes through ``Out``: rich progress and live views on a terminal, plain lines
(one event per line, ``key=value`` fields) when stdout is a pipe or a file.
"""

from __future__ import annotations

import contextlib
import json
import math
import os
import signal
import sys
import tempfile
import time
from collections.abc import AsyncIterator, Awaitable, Callable, Iterator, Sequence
from contextlib import asynccontextmanager
from dataclasses import dataclass
from pathlib import Path

import anyio
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

from drivebus.app.scan import Found, scan
from drivebus.config import MachineConfig, load_config
from drivebus.errors import ConfigError, DrivebusError, DriveOffline
from drivebus.motion import Axis, Machine, open_machine
from drivebus.motion.state import AxisState
from drivebus.settings import LineSettings
from drivebus.sim.machine import SimLine, start_simulators
from drivebus.sim.wire import VirtualWire, WireFrame
from drivebus.views import axes_table, axis_line, axis_record, slaves_table, stats_lines

__all__ = [
    "Out",
    "check_config",
    "found_line",
    "home_axis",
    "jog_axis",
    "latency_timer",
    "monitor",
    "move_axis",
    "published_sim",
    "run_guarded",
    "scan_line",
    "serve_sim",
    "show_status",
    "stop_axes",
    "subset",
]


class Out:
    """Where command output goes: a rich console on a terminal, plain lines otherwise."""

    def __init__(self, interactive: bool | None = None) -> None:
        self.interactive = sys.stdout.isatty() if interactive is None else interactive
        self.console = Console(highlight=False)

    def line(self, text: str) -> None:
        """One line of output."""
        if self.interactive:
            self.console.print(text, markup=False)
        else:
            print(text, flush=True)

    def warn(self, text: str) -> None:
        """A warning on stderr."""
        print(f"warning: {text}", file=sys.stderr, flush=True)


# -- running under a signal guard ----------------------------------------------------------------


def run_guarded(fn: Callable[[], Awaitable[int]], *, interrupt_ok: bool = False) -> int:
    """Run ``fn`` in an event loop; SIGINT/SIGTERM cancel it (its cleanup, e.g. stopping
    moving axes, runs in full) and give exit status 128+signal, or 0 if ``interrupt_ok``
    (commands that run until Ctrl-C). Further signals during the cleanup are ignored."""

    async def main() -> int:
        caught: list[int] = []
        result = 0
        with anyio.open_signal_receiver(signal.SIGINT, signal.SIGTERM) as signals:
            async with anyio.create_task_group() as tg:

                async def watch() -> None:
                    async for sig in signals:
                        caught.append(int(sig))
                        tg.cancel_scope.cancel()
                        return

                async def work() -> None:
                    nonlocal result
                    result = await fn()
                    tg.cancel_scope.cancel()

                tg.start_soon(watch)
                tg.start_soon(work)
        if caught:
            if not interrupt_ok:
                name = signal.Signals(caught[0]).name
                print(f"interrupted ({name})", file=sys.stderr, flush=True)
            return 0 if interrupt_ok else 128 + caught[0]
        return result

    return anyio.run(main)


# -- machine helpers -----------------------------------------------------------------------------


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


async def _first_status(m: Machine, timeout: float = 5.0) -> None:
    """Wait until every axis has a status from its actor's poll."""

    async def one(ax: Axis) -> None:
        if ax.status is not None:
            return
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


def _fmt(v: float | None) -> str:
    return "-" if v is None else f"{v:.3f}"


# -- scan ----------------------------------------------------------------------------------------


def found_line(f: Found) -> str:
    """One slave found by a scan, as a line."""
    detail = f" ({f.detail})" if f.detail else ""
    return f"address {f.address} at {f.settings}: {f.family}{detail}"


async def scan_line(
    out: Out, port: str, settings: list[LineSettings], addresses: list[int], timeout: float,
    *, quiet: bool = False,
) -> list[Found]:
    """Scan ``port`` with a progress bar (terminal) or a line per slave found."""
    if quiet or not out.interactive:

        def report(a: int, s: LineSettings, hit: Found | None) -> None:
            if hit is not None and not quiet:
                print(f"found {found_line(hit)}", flush=True)

        return await scan(port, settings, addresses, timeout=timeout, on_probe=report)
    with Progress(TextColumn("{task.description}"), BarColumn(), MofNCompleteColumn(),
                  console=out.console) as prog:
        task = prog.add_task("scanning", total=len(settings) * len(addresses))

        def show(a: int, s: LineSettings, hit: Found | None) -> None:
            extra = 0
            if hit is not None:
                extra = len(settings) - settings.index(s) - 1  # not probed again
                prog.console.print(f"found {found_line(hit)}", markup=False)
            prog.update(task, advance=1 + extra, description=f"scanning {s} address {a:>3}")

        return await scan(port, settings, addresses, timeout=timeout, on_probe=show)


# -- status, stop --------------------------------------------------------------------------------


async def show_status(out: Out, config: Path, axes: Sequence[str], as_json: bool) -> int:
    """Print the named axes' (or all axes') status; exit status 1 if any is in alarm."""
    cfg = subset(load_config(config), axes)
    async with open_machine(cfg, stop_on_exit=False) as m:  # looking must not stop anything
        await _first_status(m)
        if as_json:
            print(json.dumps([axis_record(m, n) for n in m.axes], indent=2), flush=True)
        elif out.interactive:
            out.console.print(axes_table(m))
        else:
            for n in m.axes:
                out.line(axis_line(m, n))
        alarms = [n for n, a in m.axes.items() if a.status is not None and a.status.alarm]
    return 1 if alarms else 0


async def stop_axes(out: Out, config: Path, axes: Sequence[str]) -> int:
    """Stop the named axes (all if none), each with its decelerating stop."""
    cfg = subset(load_config(config), axes)
    async with open_machine(cfg) as m:
        await _first_status(m)

        async def stop(name: str, ax: Axis) -> None:
            moving = ax.status is not None and ax.status.moving
            await ax.stop()
            what = "stopped" if moving else "at standstill"
            out.line(f"{name}: {what} at position={_fmt(ax.position)} state={ax.state}")

        async with anyio.create_task_group() as tg:
            for name, ax in m.axes.items():
                tg.start_soon(stop, name, ax)
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
    """One axis operation: what it is, when it started, whether it completed."""

    axis: Axis
    what: str = ""
    started: float = 0.0
    done: bool = False

    @property
    def commanded(self) -> bool:
        """True if the drive accepted a command of this operation (it may have moved)."""
        return self.axis.command_started_at >= self.started


@asynccontextmanager
async def _one_axis(out: Out, config: Path, axis: str) -> AsyncIterator[_Run]:
    """Open the machine with just ``axis``; once it is closed again (every moving axis
    stopped and at standstill), report where an operation that did not complete left it."""
    cfg = subset(load_config(config), [axis])
    run: _Run | None = None
    try:
        async with open_machine(cfg) as m:
            await _first_status(m)
            run = _Run(m.axes[axis])
            yield run
    finally:
        if run is not None and run.what and not run.done and run.commanded:
            ax = run.axis
            out.line(f"{ax.name}: {run.what} stopped after "
                     f"{time.monotonic() - run.started:.2f} s, "
                     f"position={_fmt(ax.position)} state={ax.state}")


async def _with_progress(
    out: Out, run: _Run, what: str, start: float | None, goal: float | None,
    motion: Callable[[], Awaitable[object]],
) -> None:
    """Run ``motion`` while showing its progress; a report line when it completes."""
    ax = run.axis
    run.what, run.started = what, time.monotonic()
    async with anyio.create_task_group() as tg:
        tg.start_soon(_progress, out, ax, what, start, goal)
        await motion()
        run.done = True
        tg.cancel_scope.cancel()
    out.line(f"{ax.name}: {what} done in {time.monotonic() - run.started:.2f} s, "
             f"position={_fmt(ax.position)} state={ax.state}")


async def move_axis(
    out: Out, config: Path, axis: str, target: float, by: bool, speed: float | None
) -> int:
    """Move one axis to ``target`` (or by it); Ctrl-C stops the axis before exiting."""
    async with _one_axis(out, config, axis) as run:
        ax = run.axis
        start = ax.position
        goal = (start or 0.0) + target if by else target
        what = f"move {'by' if by else 'to'} {target:g}"

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
        method = run.axis.config.homing.method or "the drive's default"
        await _with_progress(out, run, f"home ({method})", None, None, run.axis.home)
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
                            if ax.state is not AxisState.CONTINUOUS_MOTION:
                                out.warn(f"axis {axis}: jog ended by the axis ({ax.state}"
                                         f"{f': {ax.error}' if ax.error else ''})")
                                return

        await _with_progress(out, run, what, None, None, motion)
    return 0


# -- monitor ---------------------------------------------------------------------------------------


async def monitor(out: Out, config: Path, interval: float, count: int | None) -> int:
    """Show every axis and the per-slave bus counters until Ctrl-C (or ``count`` updates)."""
    async with open_machine(config, stop_on_exit=False) as m:  # an observer
        await _first_status(m)
        n = 0
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


# -- the standalone simulator ---------------------------------------------------------------------


def _registry_dir() -> Path:
    base = os.environ.get("XDG_RUNTIME_DIR") or tempfile.gettempdir()
    return Path(base) / f"drivebus-{os.getuid()}" / "sim"


def published_sim(name: str) -> str | None:
    """The pty path a running ``drivebus sim`` serves ``sim://name`` on, if one does."""
    try:
        pid_text, path = (_registry_dir() / name).read_text().split("\n")[:2]
        os.kill(int(pid_text), 0)
    except (OSError, ValueError):
        return None
    return path if Path(path).exists() else None


@contextlib.contextmanager
def _publish(sims: dict[str, SimLine]) -> Iterator[None]:
    """Record the pty path of each simulated serial line, for ``sim://NAME`` in other
    processes (``drivebus scan``); removed on exit."""
    d = _registry_dir()
    files = []
    try:
        d.mkdir(parents=True, exist_ok=True)
        for s in sims.values():
            if isinstance(s.server, VirtualWire):
                f = d / s.config.sim_name
                f.write_text(f"{os.getpid()}\n{s.endpoint}\n")
                files.append(f)
    except OSError as exc:
        print(f"warning: cannot publish the simulator's pty paths in {d}: {exc}",
              file=sys.stderr)
    try:
        yield
    finally:
        for f in files:
            f.unlink(missing_ok=True)


def _describe(sim: SimLine, cfg: MachineConfig) -> list[str]:
    kind = sim.config.kind
    lines = [f"line {sim.name} {kind} {sim.endpoint}"]
    for axis, twin in sim.twins.items():
        ac = cfg.axes[axis]
        where = "unit" if kind == "tcp" else "slave"
        settings = "" if kind == "tcp" else f" {twin.settings}"
        lines.append(f"  {where} {twin.address} {ac.drive}{settings} (axis {axis})")
    return lines


def _frame_line(line: str, f: WireFrame) -> str:
    note = f" [{f.note}]" if f.note else ""
    return (f"{f.start:.6f} {line} {f.direction:<7} addr={f.address} "
            f"{str(f.settings).replace(' ', '-')} gap={f.gap * 1000:.2f}ms "
            f"{f.data.hex(' ')}{note}")


async def _print_wire_log(name: str, wire: VirtualWire) -> None:
    seen = wire.frames
    while True:
        await wire.wait_frames(seen + 1)
        new = wire.frames - seen
        seen = wire.frames
        for f in list(wire.log)[-new:]:
            print(_frame_line(name, f), flush=True)


async def serve_sim(out: Out, config: Path, log: bool) -> int:
    """Serve the ``sim://`` lines of ``config`` (a twin per axis) until Ctrl-C/SIGTERM."""
    cfg = load_config(config)
    for ln in cfg.lines.values():
        if ln.simulated and ln.kind == "serial" and (path := published_sim(ln.sim_name)):
            raise DrivebusError(
                f"{ln.port} is already served by another drivebus sim, on {path}: use that "
                f"one, or stop it first"
            )
    async with contextlib.AsyncExitStack() as stack:
        sims = await start_simulators(cfg, stack)
        if not sims:
            raise ConfigError(f"{config}: no sim:// lines: nothing to simulate")
        with _publish(sims):
            for s in sims.values():
                for text in _describe(s, cfg):
                    print(text, flush=True)
            print(f"simulating machine {cfg.name}: Ctrl-C or SIGTERM ends it", flush=True)
            try:
                async with anyio.create_task_group() as tg:
                    if log:
                        for s in sims.values():
                            if isinstance(s.server, VirtualWire):
                                tg.start_soon(_print_wire_log, s.name, s.server)
                    await anyio.sleep_forever()
            finally:
                for s in sims.values():
                    for axis, twin in s.twins.items():
                        print(f"twin {axis}: position={twin.position()} pulses "
                              f"moving={twin.is_moving()}", flush=True)
    return 0


# -- check ---------------------------------------------------------------------------------------


def latency_timer(port: str, sysfs: Path = Path("/sys")) -> int | None:
    """The USB-serial adapter's latency timer (ms) behind ``port``, if it has one."""
    tty = Path(os.path.realpath(port)).name
    f = sysfs / "bus" / "usb-serial" / "devices" / tty / "latency_timer"
    try:
        return int(f.read_text().strip())
    except (OSError, ValueError):
        return None


def _check_serial(port: str, sysfs: Path) -> tuple[list[str], list[str]]:
    """(problems, warnings) for a real serial port."""
    if not os.path.exists(port):
        return [f"port {port} does not exist: plug in the adapter, check the name "
                f"(ls /dev/serial/by-id/)"], []
    if not os.access(port, os.R_OK | os.W_OK):
        return [f"no permission to open {port}: add your user to its group "
                f"(sudo usermod -aG dialout $USER) and log in again"], []
    warnings = []
    lt = latency_timer(port, sysfs)
    if lt is not None and lt > 1:
        tty = Path(os.path.realpath(port)).name
        warnings.append(
            f"{port}: the USB-serial latency timer is {lt} ms: every reply waits up to "
            f"{lt} ms in the adapter, capping the line at about {1000 // (lt + 1)} "
            f"transactions/s; set it to 1 ms: echo 1 | sudo tee "
            f"/sys/bus/usb-serial/devices/{tty}/latency_timer (or a udev rule)"
        )
    if "/pts/" in os.path.realpath(port):
        warnings.append(f"{port} is a pty (a simulator or virtual port): parity and byte "
                        f"size are not carried; keep its slaves at 8N1/8N2")
    return [], warnings


def check_config(out: Out, config: Path, sysfs: Path = Path("/sys")) -> int:
    """Validate ``config`` and report on its lines; exit status 1 if a line cannot work."""
    cfg = load_config(config)
    problems: list[str] = []
    out.line(f"{config}: valid machine {cfg.name!r}: {len(cfg.axes)} axes on "
             f"{len(cfg.lines)} lines")
    for name, ln in cfg.lines.items():
        axes = [f"{n} ({a.drive} @{a.address})" for n, a in cfg.axes.items() if a.line == name]
        on = ", ".join(axes) or "no axes"
        if ln.simulated:
            out.line(f"line {name}: simulated ({ln.port or ln.host}, {ln.kind}): {on}")
            continue
        if ln.kind == "serial":
            assert ln.port is not None
            out.line(f"line {name}: serial port {ln.port} at {ln.settings}: {on}")
            bad, warns = _check_serial(ln.port, sysfs)
            problems += [f"line {name}: {p}" for p in bad]
            for w in warns:
                out.warn(f"line {name}: {w}")
        else:
            out.line(f"line {name}: {ln.kind} {ln.host}:{ln.tcp_port}: {on}")
    for p in problems:
        print(f"error: {p}", file=sys.stderr, flush=True)
    return 1 if problems else 0
