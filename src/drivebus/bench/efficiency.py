"""Bench scenario "efficiency": slaves polled as fast as the bus allows, against the wire limit."""

from __future__ import annotations

import time
from collections.abc import Sequence
from dataclasses import asdict

from drivebus.bench.common import (
    MIXED,
    S9600,
    S19200,
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
from drivebus.settings import LineSettings
from drivebus.sim.wire import VirtualWire

__all__ = ["SCENARIO", "efficiency"]


async def efficiency(
    label: str, settings: Sequence[LineSettings], n: int, seconds: float, turnaround: float
) -> BenchResult:
    """``n`` slaves (settings taken in turn) polled as fast as the bus allows."""
    slaves = register_slaves(n, settings, turnaround)
    async with VirtualWire(f"bench-eff-{label}-{n}") as wire:
        for s in slaves:
            wire.attach(s)
        async with Bus(SerialLine(wire.url, settings[0])) as bus:
            handles = [bus.slave(s.address, settings=s.settings) for s in slaves]
            await poll_until(handles, time.monotonic() + 0.2)  # warm-up
            wire.clear_log()
            c0 = time.process_time()
            await poll_until(handles, time.monotonic() + seconds)
            cpu = time.process_time() - c0
        fig = wire_figures(list(wire.log), turnaround)
    row = asdict(fig)
    row["cpu_us_per_tx_incl_sim"] = cpu / max(fig.transactions, 1) * 1e6
    return BenchResult("efficiency", f"{label} x{n}", row)


async def run(opts: BenchOptions) -> list[BenchResult]:
    """Every setting (and the mixed line) with 1, 8 and 31 slaves (quick: 1 and 8)."""
    cases = [("9600 8N1", [S9600]), ("19200 8E1", [S19200]), ("115200 8N1", [S115200]),
             ("mixed", list(MIXED))]
    counts = (1, 8) if opts.quick else (1, 8, 31)
    return [
        await efficiency(label, settings, n, opts.seconds, opts.turnaround)
        for label, settings in cases
        for n in counts
    ]


SCENARIO = Scenario("efficiency", 10, run)
