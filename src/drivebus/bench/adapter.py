"""Bench scenario "adapter": what a USB adapter's latency timer costs a line.

Most USB-RS485 adapters are FTDI, whose driver holds received bytes up to its latency
timer (16 ms by default) unless the port is in low-latency mode (1 ms), which drivebus
asks for when it opens a port. One slave in another process is polled back to back
(4-register reads at 115200 8N1) behind a simulated adapter with no timer, a 1 ms one
and a 16 ms one: transactions per second and the line's efficiency (the wire limit's
share, judged on the other process's wire log) show the difference.
"""

from __future__ import annotations

import time

from drivebus.bench.common import (
    S115200,
    BenchOptions,
    BenchResult,
    Scenario,
    SimProcess,
    at_least,
    poll_until,
)
from drivebus.bus import Bus
from drivebus.line.serial import SerialLine
from drivebus.timing import timing

__all__ = ["SCENARIO", "adapter_cost"]


async def adapter_cost(latency: float, seconds: float, turnaround: float) -> BenchResult:
    """Poll one slave for ``seconds`` behind an adapter with a ``latency`` s timer."""
    async with SimProcess.slaves(1, [S115200], turnaround, adapter_latency=latency) as sim:
        async with Bus(SerialLine(sim.paths[0], S115200), timeout=0.1) as bus:
            await sim.clear()
            start = time.monotonic()
            await poll_until([bus.slave(1)], start + seconds, 1, registers=4)
            elapsed = time.monotonic() - start
        frames = next(iter((await sim.logs()).values()))
    replies = [f for f in frames if f.direction == "reply"]
    wire = timing(S115200).transaction_time(8, 13, turnaround)
    rate = len(replies) / elapsed
    case = "no timer" if latency == 0 else f"{latency * 1e3:g} ms timer"
    figures = {"transactions_per_s": rate, "efficiency": rate * wire,
               "wire_limit_per_s": 1 / wire}
    targets = {"efficiency": at_least(0.5)} if latency <= 0.001 else {}
    return BenchResult("adapter", f"{S115200} 1 slave, {case}", figures, targets)


async def run(opts: BenchOptions) -> list[BenchResult]:
    """No timer, 1 ms and 16 ms (quick: 1 s each)."""
    seconds = 1.0 if opts.quick else opts.seconds
    return [await adapter_cost(lat, seconds, opts.turnaround) for lat in (0.0, 0.001, 0.016)]


SCENARIO = Scenario("adapter", 15, run)
