"""The demo job: home, a coordinated multi-axis sequence, a jog and a stop, on the simulator."""

from __future__ import annotations

import contextlib
import sys
import time
from collections.abc import Awaitable, Callable
from pathlib import Path

import anyio
from rich.console import Console
from rich.live import Live

from drivebus.cli.views import axes_table
from drivebus.config import load_config
from drivebus.errors import ArgumentError, ConfigError, MotionAborted, NotSupported
from drivebus.machines import DEMO
from drivebus.motion import Axis, Machine, open_machine
from drivebus.motion.state import AxisState

__all__ = ["DEFAULT_CONFIG", "axes_table", "run_demo", "write_demo"]

DEFAULT_CONFIG = DEMO
"""The machine ``drivebus demo`` runs without an argument: the packaged demo machine."""


async def _step(log: Callable[[str], None], what: str, fn: Callable[[], Awaitable[object]]) -> None:
    t0 = time.monotonic()
    await fn()
    log(f"{what}: done in {time.monotonic() - t0:.2f} s")


def _span(ax: Axis, fraction: float) -> float:
    """A position ``fraction`` of the way through the axis's soft limits (or of a range
    around where it is, without limits)."""
    lim = ax.config.limits
    if lim is None:
        here = ax.position or 0.0
        lim = (here - ax.config.speed, here + ax.config.speed)
    return lim[0] + fraction * (lim[1] - lim[0])


def _can(ax: Axis, procedure: str) -> bool:
    try:
        ax.profile.check_supported(procedure)
    except NotSupported:
        return False
    return True


async def _job(m: Machine, log: Callable[[str], None]) -> int:
    movers = [ax for ax in m.axes.values() if _can(ax, "move_absolute")]
    if not movers:
        drives = ", ".join(f"{n}: {a.profile.family}" for n, a in m.axes.items())
        raise ConfigError(
            f"the demo needs an axis whose drive makes position moves; machine "
            f"{m.config.name}'s drives cannot ({drives})"
        )
    names = [ax.name for ax in movers]
    motion = m.group(*names)
    for ax in movers:
        with contextlib.suppress(NotSupported):  # a drive without an enable needs none
            await ax.enable()
    homers = [ax for ax in movers if ax.config.homing.method is not None and _can(ax, "home")]
    if homers:
        together = " in parallel" if len(homers) > 1 else ""
        await _step(log, f"home {', '.join(a.name for a in homers)}{together}",
                    m.group(*(a.name for a in homers)).home)
    moves = 0
    for fraction in (0.25, 0.6, 0.1):
        targets = {ax.name: round(_span(ax, fraction), 3) for ax in movers}
        report = await motion.move_to(targets)
        moves += 1
        log(f"group move to {targets}: planned {report.duration:.2f} s, "
            f"start skew {report.start_skew * 1000:.1f} ms, "
            f"arrival spread planned {report.planned_arrival_spread * 1000:.1f} ms, "
            f"observed {report.observed_arrival_spread * 1000:.0f} ms "
            f"(polls every {report.observed_resolution * 1000:.0f} ms)")
    jogger = movers[-1]
    speed = jogger.config.speed / 4
    async with jogger.jogging(+speed):
        log(f"jog {jogger.name} at +{speed:g}/s for 0.5 s")
        await anyio.sleep(0.5)
    log(f"jog ended: {jogger.name} stopped at {jogger.position:.3f}")
    first = movers[0]
    far, midway = _span(first, 0.9), _span(first, 0.5)

    async def stop_midway() -> None:
        async for _st in first.watch():
            if first.position is not None and first.position > midway:
                await first.stop()
                return

    async with anyio.create_task_group() as tg:
        tg.start_soon(stop_midway)  # returns once the stop has brought it to standstill
        try:
            await first.move_to(far)
        except MotionAborted as exc:
            log(f"{first.name} move_to({far:g}) ended by a stop: {exc}")
    log(f"{first.name} stopped at {first.position:.3f}, state {first.state}")
    home = _span(first, 0.0) if first.config.limits is None else max(
        first.config.limits[0], min(0.0, first.config.limits[1]))
    await _step(log, f"{first.name} back to {home:g}", lambda: first.move_to(home))
    moves += 1
    for ax in m.axes.values():
        if ax not in movers and ax.status is not None:
            log(f"{ax.name} ({ax.profile.family}, monitoring only): "
                f"enabled={ax.status.enabled} alarm={ax.status.alarm}")
    return moves


async def run_demo(config: str | Path | None = None) -> int:
    """Run the demo job on ``config`` (the built-in demo machine by default); exit status."""
    path = Path(config) if config is not None else DEFAULT_CONFIG
    console = Console()
    interactive = sys.stdout.isatty()
    lines: list[str] = []

    def log(msg: str) -> None:
        lines.append(msg)
        if interactive:
            console.log(msg)
        else:
            print(msg, flush=True)

    cfg = load_config(path)
    if config is None:
        # the built-in demo runs on simulators of its own: it never drives (or shares) the
        # lines of a drivebus sim that serves configs/demo.toml for someone else
        from drivebus.sim.machine import own_sim_lines

        cfg = own_sim_lines(cfg)
    real = [f"{n} ({ln.port or ln.host})" for n, ln in cfg.lines.items() if not ln.simulated]
    if real:
        raise ConfigError(f"{path}: the demo runs on the simulator only, and line "
                          f"{', '.join(real)} is real: give its lines sim://NAME ports")
    t0 = time.monotonic()
    async with open_machine(cfg) as m:
        log(f"machine {m.config.name}: {_count(len(m.axes), 'axis', 'axes')} on "
            f"{_count(len(m.buses), 'line', 'lines')} (simulated)")
        if interactive:
            with Live(axes_table(m), console=console, refresh_per_second=10) as live:

                async def refresh() -> None:
                    while True:
                        live.update(axes_table(m))
                        await anyio.sleep(0.1)

                async with anyio.create_task_group() as tg:
                    tg.start_soon(refresh)
                    moves = await _job(m, log)
                    tg.cancel_scope.cancel()
                live.update(axes_table(m))
        else:
            moves = await _job(m, log)
            Console(file=sys.stdout, width=110).print(axes_table(m))
        errors = sum(b.stats.total().errors for b in m.buses.values())
        tx = sum(b.stats.transactions for b in m.buses.values())
        util = {n: f"{b.stats.utilisation:.0%}" for n, b in m.buses.items()}
        faulted = [n for n, a in m.axes.items() if a.state is AxisState.ERROR_STOP]
        violations = sum(getattr(w, "violations", 0) for w in m.wires.values())
    print(
        f"summary: {moves} coordinated/point moves, {tx} transactions, {errors} errors, "
        f"line utilisation {util}, gap violations {violations}, "
        f"{time.monotonic() - t0:.1f} s",
        flush=True,
    )
    return 1 if faulted or violations else 0


def write_demo(dest: str | Path) -> Path:
    """Copy the built-in demo machine file to ``dest`` (into it, if it is a folder) and
    return where it went; an existing file is never overwritten (``ArgumentError``)."""
    target = Path(dest)
    if target.is_dir():
        target = target / DEFAULT_CONFIG.name
    try:
        with target.open("x", encoding="utf-8") as out:
            out.write(DEFAULT_CONFIG.read_text(encoding="utf-8"))
    except FileExistsError:
        raise ArgumentError(f"--write: {target} exists; the demo machine is written only to "
                            "a new file (remove it or name another)") from None
    except OSError as exc:
        raise ArgumentError(f"--write: cannot write {target}: {exc.strerror}") from None
    return target


def _count(n: int, one: str, many: str) -> str:
    return f"{n} {one if n == 1 else many}"
