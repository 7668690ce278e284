"""Bench scenario "cpu": the master stack's own CPU per transaction, beside the bare floor.

The floor is the least any asyncio master can do per round trip on this machine and
interpreter: one precise timer wait (timerfd), one write to the pty and one read wake-up,
no drivebus layers. drivebus and the floor run in turns (A B A B ...) against the same
slave in another process, so that load from elsewhere hits both alike; the ratio is taken
pair by pair and its median reported.
"""

from __future__ import annotations

import asyncio
import os
import statistics
import time

import serial

from drivebus.bench.common import BenchOptions, BenchResult, Scenario, SimProcess, at_most
from drivebus.bus import Bus
from drivebus.clock import PreciseTimer
from drivebus.line.rtu import frame as rtu_frame
from drivebus.line.serial import SerialLine
from drivebus.settings import LineSettings
from drivebus.timing import timing

__all__ = ["RATIO_TARGET", "SCENARIO", "cpu_per_transaction", "round_trip_floor"]

RATIO_TARGET = 1.25
FAST = LineSettings(baudrate=4_000_000, parity="N")
"""A rate at which the wire time is negligible: what is left is the stack (t3.5 is the
fixed 1.75 ms of every rate above 19200)."""


async def drivebus_round_trips(path: str, seconds: float) -> tuple[int, float]:
    """Back-to-back reads through ``Bus`` for ``seconds``: (transactions, CPU µs each)."""
    async with Bus(SerialLine(path, FAST)) as bus:
        h = bus.slave(1)
        for _ in range(50):
            await h.read_holding_registers(0, 2)
        n0 = bus.stats.transactions
        c0 = time.process_time()
        deadline = time.monotonic() + seconds
        while time.monotonic() < deadline:
            await h.read_holding_registers(0, 2)
        n = bus.stats.transactions - n0
        return n, (time.process_time() - c0) / max(n, 1) * 1e6


async def round_trip_floor(path: str, settings: LineSettings, seconds: float) -> float:
    """CPU µs per round trip of the bare minimum on this machine: one precise timer wait,
    one write and one read wake-up on the same pty, no drivebus layers. It is the floor
    under ``cpu_per_transaction`` that only a faster machine or interpreter can lower."""
    loop = asyncio.get_running_loop()
    port = serial.serial_for_url(path, baudrate=settings.baudrate, timeout=0)
    fd = port.fileno()
    timer = PreciseTimer()
    buf = bytearray()
    waiter: list[asyncio.Future[None]] = []

    def readable() -> None:
        buf.extend(os.read(fd, 1024))
        if len(buf) >= 9 and waiter and not waiter[0].done():
            waiter[0].set_result(None)

    loop.add_reader(fd, readable)
    request = rtu_frame(1, bytes.fromhex("0300000002"))
    try:
        n = 0
        c0 = time.process_time()
        deadline = time.monotonic() + seconds
        while time.monotonic() < deadline:
            await timer.sleep_until(time.monotonic() + timing(settings).t35)
            buf.clear()
            waiter[:] = [loop.create_future()]
            os.write(fd, request)
            await waiter[0]
            n += 1
        return (time.process_time() - c0) / n * 1e6
    finally:
        loop.remove_reader(fd)
        timer.close()
        port.close()


async def cpu_per_transaction(seconds: float, rounds: int = 5) -> BenchResult:
    """drivebus and the floor in ``rounds`` turns of ``seconds`` each."""
    ours: list[float] = []
    floor: list[float] = []
    tps: list[float] = []
    async with SimProcess.slaves(1, [FAST], 0.0) as sim:
        for _ in range(rounds):
            n, us = await drivebus_round_trips(sim.paths[0], seconds)
            ours.append(us)
            tps.append(n / seconds)
            floor.append(await round_trip_floor(sim.paths[0], FAST, seconds))
    ratios = [a / b for a, b in zip(ours, floor, strict=True)]
    return BenchResult(
        "cpu",
        f"4 Mbaud, turnaround 0, {rounds} turns",
        {
            "master_cpu_us_per_tx": statistics.median(ours),
            "master_cpu_us_min": min(ours),
            "floor_cpu_us_per_tx": statistics.median(floor),
            "floor_cpu_us_min": min(floor),
            "ratio": statistics.median(ratios),
            "ratio_min": min(ratios),
            "tps": statistics.median(tps),
        },
        {"ratio": at_most(RATIO_TARGET)},
    )


async def run(opts: BenchOptions) -> list[BenchResult]:
    """Five turns (quick: three) at 4 Mbaud with a zero-turnaround slave elsewhere."""
    rounds = 3 if opts.quick else 5
    return [await cpu_per_transaction(max(opts.seconds / 2, 0.2), rounds)]


SCENARIO = Scenario("cpu", 30, run)
