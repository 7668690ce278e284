"""Bench scenario "scale": many lines with many slaves each, all polling, in one process."""

from __future__ import annotations

import contextlib
import statistics
import time

import anyio

from drivebus.bench.common import (
    S115200,
    BenchOptions,
    BenchResult,
    Scenario,
    poll_until,
    register_slaves,
    wire_figures,
)
from drivebus.bus import Bus
from drivebus.line.serial import SerialLine
from drivebus.sim.wire import VirtualWire

__all__ = ["SCENARIO", "scale"]


async def scale(lines: int, axes: int, seconds: float, turnaround: float) -> BenchResult:
    """``lines`` lines at 115200 with ``axes`` slaves each, polled together."""
    settings = S115200
    effs: list[float] = []
    viol = 0
    async with contextlib.AsyncExitStack() as stack:
        wires = []
        buses = []
        for i in range(lines):
            wire = await stack.enter_async_context(VirtualWire(f"bench-scale-{i}"))
            for s in register_slaves(axes, [settings], turnaround):
                wire.attach(s)
            bus = await stack.enter_async_context(Bus(SerialLine(wire.url, settings)))
            wires.append(wire)
            buses.append(bus)
        c0, t0 = time.process_time(), time.monotonic()
        async with anyio.create_task_group() as tg:
            for bus in buses:
                tg.start_soon(poll_until, [bus.slave(a) for a in range(1, axes + 1)],
                              t0 + seconds)
        load = (time.process_time() - c0) / (time.monotonic() - t0)
        for w in wires:
            fig = wire_figures(list(w.log), turnaround)
            effs.append(fig.efficiency)
            viol += fig.violations
    return BenchResult(
        "scale",
        f"{lines} lines x {axes} axes, {settings}",
        {"eff_mean": statistics.mean(effs), "eff_min": min(effs), "violations": viol,
         "cpu_load_cores": load},
    )


async def run(opts: BenchOptions) -> list[BenchResult]:
    """16 lines x 8 axes (quick: 4 x 8)."""
    return [await scale(4 if opts.quick else 16, 8, opts.seconds, opts.turnaround)]


SCENARIO = Scenario("scale", 40, run)
