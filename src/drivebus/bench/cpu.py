"""Bench scenario "cpu": the master stack's own CPU per transaction, beside the bare floor."""

from __future__ import annotations

import asyncio
import os
import time

import serial

from drivebus.bench.common import BenchOptions, BenchResult, Scenario, wire_in_process
from drivebus.bus import Bus
from drivebus.clock import PreciseTimer
from drivebus.line.rtu import frame as rtu_frame
from drivebus.line.serial import SerialLine
from drivebus.settings import LineSettings
from drivebus.timing import timing

__all__ = ["SCENARIO", "cpu_per_transaction", "round_trip_floor"]


async def cpu_per_transaction(seconds: float) -> BenchResult:
    """The master stack's own CPU per transaction, the wire out of the way.

    The simulated wire runs in a child process so this process's CPU time is the
    stack's alone: scheduler, line, framing, timers and the event loop.
    """
    fast = LineSettings(baudrate=4_000_000, parity="N")
    with wire_in_process(1, fast, 0.0) as path:
        async with Bus(SerialLine(path, fast)) as bus:
            h = bus.slave(1)
            for _ in range(200):
                await h.read_holding_registers(0, 2)
            n0 = bus.stats.transactions
            c0, t0 = time.process_time(), time.monotonic()
            deadline = t0 + seconds
            while time.monotonic() < deadline:
                await h.read_holding_registers(0, 2)
            cpu, wall = time.process_time() - c0, time.monotonic() - t0
            n = bus.stats.transactions - n0
        floor = await round_trip_floor(path, fast, seconds)
    return BenchResult(
        "cpu",
        "4 Mbaud, turnaround 0",
        {"transactions": n, "tps": n / wall, "master_cpu_us_per_tx": cpu / n * 1e6,
         "floor_cpu_us_per_tx": floor},
    )


async def round_trip_floor(path: str, settings: LineSettings, seconds: float) -> float:
    """CPU per round trip of the bare minimum on this machine: one precise timer wait,
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


async def run(opts: BenchOptions) -> list[BenchResult]:
    """One run at 4 Mbaud with a zero-turnaround slave in a child process."""
    return [await cpu_per_transaction(opts.seconds)]


SCENARIO = Scenario("cpu", 30, run)
