"""Bench scenario "stop latency": emergency writes into a line saturated by polls."""

from __future__ import annotations

import random
import time

import anyio
import anyio.abc

from drivebus.bench.common import (
    S19200,
    S115200,
    BenchOptions,
    BenchResult,
    Scenario,
    percentile,
    poll_until,
    register_slaves,
)
from drivebus.bus import Bus, Priority
from drivebus.line.serial import SerialLine
from drivebus.settings import LineSettings
from drivebus.sim.wire import VirtualWire
from drivebus.timing import timing

__all__ = ["SCENARIO", "stop_latency"]


async def stop_latency(settings: LineSettings, stops: int, turnaround: float) -> BenchResult:
    """``stops`` emergency writes at random moments into polls from 8 axes (2 readers each);
    latency is from the call to the stop's first byte on the wire."""
    slaves = register_slaves(8, [settings], turnaround)
    rng = random.Random(7)
    lat: list[float] = []
    async with VirtualWire(f"bench-stop-{settings.baudrate}") as wire:
        for s in slaves:
            wire.attach(s)
        async with Bus(SerialLine(wire.url, settings)) as bus:
            handles = [bus.slave(s.address) for s in slaves]
            done = time.monotonic() + 3600

            async def stopper(tg: anyio.abc.TaskGroup) -> None:
                for i in range(stops):
                    await anyio.sleep(rng.uniform(0.0, 0.02))
                    h = handles[i % 8]
                    t_call = time.monotonic()
                    await h.write_register(10, i & 0xFFFF, priority=Priority.EMERGENCY)
                    # the newest write on the wire is this stop: only the stopper writes
                    stop = next(f for f in reversed(wire.log)
                                if f.direction == "request" and f.data[1] == 0x06)
                    lat.append(stop.start - t_call)
                tg.cancel_scope.cancel()

            async with anyio.create_task_group() as tg:
                tg.start_soon(poll_until, handles, done, 2)
                tg.start_soon(stopper, tg)
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
            "target_us": (tx + tm.t35) * 1e6,
        },
    )


async def run(opts: BenchOptions) -> list[BenchResult]:
    """200 stops at 19200 and at 115200 (quick: 20 at 115200)."""
    if opts.quick:
        return [await stop_latency(S115200, 20, opts.turnaround)]
    return [await stop_latency(s, 200, opts.turnaround) for s in (S19200, S115200)]


SCENARIO = Scenario("stop latency", 20, run)
