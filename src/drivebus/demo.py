"""The demo job: home, a coordinated multi-axis sequence, a jog and a stop, on the simulator."""

from __future__ import annotations

import sys
import time
from collections.abc import Awaitable, Callable
from pathlib import Path

import anyio
from rich.console import Console
from rich.live import Live

from drivebus.errors import MotionAborted
from drivebus.motion import Machine, open_machine
from drivebus.motion.state import AxisState
from drivebus.views import axes_table

__all__ = ["DEFAULT_CONFIG", "axes_table", "run_demo"]

DEFAULT_CONFIG = Path(__file__).resolve().parents[2] / "configs" / "demo.toml"


async def _step(log: Callable[[str], None], what: str, fn: Callable[[], Awaitable[object]]) -> None:
    t0 = time.monotonic()
    await fn()
    log(f"{what}: done in {time.monotonic() - t0:.2f} s")


async def _job(m: Machine, log: Callable[[str], None]) -> int:
    x, y, z, r = (m.axes[n] for n in ("x", "y", "z", "r"))
    motion = m.group("x", "y", "z", "r")
    for ax in (x, y, z, r):
        await ax.enable()
    await _step(log, "home x, y, z, r in parallel", motion.home)
    moves = 0
    for targets in ({"x": 100.0, "y": 50.0, "z": 30.0, "r": 360.0},
                    {"x": 250.0, "y": 120.0, "z": 60.0, "r": 0.0},
                    {"x": 20.0, "y": 10.0, "z": 5.0, "r": 180.0}):
        report = await motion.move_to(targets)
        moves += 1
        log(f"group move to {targets}: planned {report.duration:.2f} s, "
            f"start skew {report.start_skew * 1000:.1f} ms")
    async with z.jogging(+10.0):
        log("jog z at +10 mm/s for 0.5 s")
        await anyio.sleep(0.5)
    log(f"jog ended: z stopped at {z.position:.3f} mm")

    async def stop_x_midway() -> None:
        async for _st in x.watch():
            if x.position is not None and x.position > 150.0:
                await x.stop()
                return

    async with anyio.create_task_group() as tg:
        tg.start_soon(stop_x_midway)  # returns once the stop has brought x to standstill
        try:
            await x.move_to(380.0)
        except MotionAborted as exc:
            log(f"x move_to(380) ended by a stop: {exc}")
    log(f"x stopped at {x.position:.3f} mm, state {x.state}")
    await _step(log, "x back to 0", lambda: x.move_to(0.0))
    moves += 1
    aux = m.axes["aux"]
    if aux.status is not None:
        log(f"aux ({aux.profile.family}): enabled={aux.status.enabled} alarm={aux.status.alarm}")
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

    t0 = time.monotonic()
    async with open_machine(path) as m:
        log(f"machine {m.config.name}: {len(m.axes)} axes on {len(m.buses)} lines (simulated)")
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
        wire = m.wires.get("rs485")
        violations = getattr(wire, "violations", 0)
    print(
        f"summary: {moves} coordinated/point moves, {tx} transactions, {errors} errors, "
        f"line utilisation {util}, gap violations {violations}, "
        f"{time.monotonic() - t0:.1f} s",
        flush=True,
    )
    return 1 if faulted or violations else 0
