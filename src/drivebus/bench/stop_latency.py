"""Bench scenario "stop latency": emergency writes into a line saturated by polls.

The slaves run in another process; each stop's latency is from the call to its first
byte on that process's wire (both on the same clock). Target: within the transaction in
flight plus one silence (p99).
"""

from __future__ import annotations

import random
import time

import anyio
import anyio.abc

from drivebus.bench.common import (
    S115200,
    BenchOptions,
    BenchResult,
    Scenario,
    SimProcess,
    at_most,
    percentile,
    poll_until,
)
from drivebus.bus import Bus, Priority
from drivebus.line.serial import SerialLine
from drivebus.settings import LineSettings
from drivebus.timing import timing

__all__ = ["SCENARIO", "stop_latency"]

S19200_8N2 = LineSettings.parse("19200 8N2")


async def stop_latency(settings: LineSettings, stops: int, turnaround: float) -> BenchResult:
    """``stops`` emergency writes at random moments into polls from 8 axes (2 readers each);
    latency is from the call to the stop's first byte on the wire."""
    rng = random.Random(7)
    called: dict[int, float] = {}
    async with SimProcess.slaves(8, [settings], turnaround) as sim:
        async with Bus(SerialLine(sim.paths[0], settings)) as bus:
            handles = [bus.slave(a) for a in range(1, 9)]
            done = time.monotonic() + 3600

            async def stopper(tg: anyio.abc.TaskGroup) -> None:
                for i in range(stops):
                    await anyio.sleep(rng.uniform(0.0, 0.02))
                    called[i] = time.monotonic()
                    await handles[i % 8].write_register(10, i, priority=Priority.EMERGENCY)
                tg.cancel_scope.cancel()

            await sim.clear()
            async with anyio.create_task_group() as tg:
                tg.start_soon(poll_until, handles, done, 2)
                tg.start_soon(stopper, tg)
        frames = next(iter((await sim.logs()).values()))
    # only the stopper writes: each FC06 request carries its stop's number
    lat = [f.start - called[int.from_bytes(f.data[4:6], "big")] for f in frames
           if f.direction == "request" and f.data[1] == 0x06]
    tm = timing(settings)
    tx = tm.transaction_time(8, 9, turnaround)
    us = [x * 1e6 for x in lat]
    return BenchResult(
        "stop latency",
        f"{settings} 8 axes",
        {
            "stops": len(lat),
            "p50_us": percentile(us, 0.5),
            "p99_us": percentile(us, 0.99),
            "max_us": max(us),
            "transaction_us": tx * 1e6,
            "p99_in_transactions": percentile(us, 0.99) / (tx * 1e6),
        },
        {"p99_us": at_most((tx + tm.t35) * 1e6)},
    )


async def run(opts: BenchOptions) -> list[BenchResult]:
    """200 stops at 19200 and at 115200 (quick: 20 at 115200)."""
    if opts.quick:
        return [await stop_latency(S115200, 20, opts.turnaround)]
    return [await stop_latency(s, 200, opts.turnaround) for s in (S19200_8N2, S115200)]


SCENARIO = Scenario("stop latency", 20, run)
