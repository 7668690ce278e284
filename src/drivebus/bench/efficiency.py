"""Bench scenario "efficiency": slaves polled as fast as the bus allows, against the wire limit.

The slaves run in another process (``SimProcess``) and the figures come from its wire log:
what the wire saw, on the same clock as the master, with nothing of the simulator in the
master's event loop or CPU time. The same run with the simulator in the master's process
is the second column (``efficiency_in_process``). The stages split the silence between a
reply and the next request: the reply reaching the master, the master's own lateness, and
the request reaching the wire.

Beside drivebus, the same slaves are polled by a bare master (``bare_poll``: a precise
timer for t3.5 after the reply's last byte, one write, one read wake-up per reply, no
drivebus layers): its efficiency and gap are the floor that this machine, its pty and
the simulator's process allow any asyncio master, which only a faster machine lowers.
The same bare master as a blocking loop in a thread of its own (``bare_poll_thread``)
shows what a dedicated I/O thread per line could reach at best.

``efficiency_recording`` is the first run again with what a recording hangs on the bus (a
``Bus.observe`` observer filling a bounded ring, as ``Machine.record`` does);
``recording_cost_points`` is what that costs, in points of efficiency.
"""

from __future__ import annotations

import asyncio
import os
import select
import time
from collections import deque
from collections.abc import Sequence

import anyio
import anyio.to_thread
import serial

from drivebus.bench.common import (
    MIXED_PTY,
    S9600,
    S115200,
    BenchOptions,
    BenchResult,
    Scenario,
    SimProcess,
    at_least,
    at_most,
    poll_until,
    record_exchanges,
    register_slaves,
    stage_figures,
    wire_figures,
)
from drivebus.bus import Bus, Transaction
from drivebus.clock import PreciseTimer
from drivebus.line.rtu import frame
from drivebus.line.serial import SerialLine
from drivebus.settings import LineSettings
from drivebus.sim.wire import VirtualWire
from drivebus.timing import switch_silence

__all__ = ["EFFICIENCY_TARGET", "GAP_EXCESS_TARGET_US", "SCENARIO", "bare_poll", "bare_poll_thread",
           "efficiency"]

EFFICIENCY_TARGET = 0.97
GAP_EXCESS_TARGET_US = 150.0
REGISTERS = 4
"""Registers per read: a drive's status block."""


async def _poll(line: SerialLine, settings: Sequence[LineSettings], n: int, seconds: float,
                clear: object, *, recording: bool = False) -> tuple[float, list]:
    async with Bus(line) as bus:
        if recording:  # what a Recording hangs on a bus: an observer filling a ring
            ring: deque[Transaction] = deque(maxlen=500_000)
            bus.observe(ring.append)
        handles = [bus.slave(a, settings=settings[(a - 1) % len(settings)])
                   for a in range(1, n + 1)]
        await poll_until(handles, time.monotonic() + 0.2, registers=REGISTERS)  # warm-up
        await clear()  # type: ignore[operator]
        exchanges = record_exchanges(line)
        c0 = time.process_time()
        await poll_until(handles, time.monotonic() + seconds, registers=REGISTERS)
        return time.process_time() - c0, exchanges


class _BareMaster:
    """What both bare masters share: the port, the requests and the settings switch."""

    def __init__(self, path: str, settings: Sequence[LineSettings], n: int) -> None:
        self.settings = settings
        self.port = serial.serial_for_url(path, baudrate=settings[0].baudrate,
                                          stopbits=settings[0].stopbits, timeout=0)
        self.fd = self.port.fileno()
        self.requests = [frame(a, bytes([3, 0, 0, 0, REGISTERS])) for a in range(1, n + 1)]
        self.reply_length = 3 + 2 * REGISTERS + 2
        self.current = settings[0]

    def switch(self, a: int) -> float:
        """Set the port for slave ``a`` (0-based); the silence its request needs."""
        target = self.settings[a % len(self.settings)]
        silence = switch_silence(self.current, target)
        if target is not self.current:
            port = self.port
            port._baudrate, port._stopbits = target.baudrate, target.stopbits
            port._reconfigure_port()  # one tcsetattr, as SerialLine does
            self.current = target
        return silence


async def bare_poll(path: str, settings: Sequence[LineSettings], n: int, seconds: float) -> int:
    """The least an asyncio master does for the same polling: slaves 1..``n`` read in turn,
    each request written ``switch_silence`` after the last reply byte arrived (precise
    timer), the reply read by its known length; no scheduler, no retries, no checks. The
    replies received (a reply missing for 0.1 s is skipped)."""
    loop = asyncio.get_running_loop()
    m = _BareMaster(path, settings, n)
    timer = PreciseTimer()
    buf = bytearray()
    last_rx = time.monotonic()
    waiter: asyncio.Future[None] = loop.create_future()

    def readable() -> None:
        nonlocal last_rx
        buf.extend(os.read(m.fd, 1024))
        last_rx = time.monotonic()
        if len(buf) >= m.reply_length and not waiter.done():
            waiter.set_result(None)

    loop.add_reader(m.fd, readable)
    try:
        replies = a = 0
        deadline = time.monotonic() + seconds
        while time.monotonic() < deadline:
            await timer.sleep_until(last_rx + m.switch(a))
            buf.clear()
            waiter = loop.create_future()
            os.write(m.fd, m.requests[a])
            try:
                await asyncio.wait_for(waiter, 0.1)
                replies += 1
            except TimeoutError:
                last_rx = time.monotonic()
            a = (a + 1) % n
        return replies
    finally:
        loop.remove_reader(m.fd)
        timer.close()
        m.port.close()


def bare_poll_thread(path: str, settings: Sequence[LineSettings], n: int, seconds: float) -> int:
    """``bare_poll`` as a blocking loop for a thread of its own (what a dedicated I/O
    thread per line could do at best): ``select`` waits for the silence and the reply."""
    m = _BareMaster(path, settings, n)
    try:
        replies = a = 0
        last_rx = time.monotonic()
        deadline = last_rx + seconds
        while time.monotonic() < deadline:
            due = last_rx + m.switch(a)
            while (left := due - time.monotonic()) > 0:
                select.select([], [], [], left)
            os.write(m.fd, m.requests[a])
            got = 0
            give_up = time.monotonic() + 0.1
            while got < m.reply_length and (left := give_up - time.monotonic()) > 0:
                if select.select([m.fd], [], [], left)[0]:
                    got += len(os.read(m.fd, 1024))
                    last_rx = time.monotonic()
            if got >= m.reply_length:
                replies += 1
            else:
                last_rx = time.monotonic()
            a = (a + 1) % n
        return replies
    finally:
        m.port.close()


async def efficiency(
    label: str, settings: Sequence[LineSettings], n: int, seconds: float, turnaround: float
) -> BenchResult:
    """``n`` slaves (settings taken in turn) polled as fast as the bus allows, the slaves
    in another process; then the same with them in this one."""
    async with SimProcess.slaves(n, settings, turnaround) as sim:
        cpu, exchanges = await _poll(SerialLine(sim.paths[0], settings[0]), settings, n,
                                     seconds, sim.clear)
        frames = next(iter((await sim.logs()).values()))
        await sim.clear()
        await _poll(SerialLine(sim.paths[0], settings[0]), settings, n, seconds, sim.clear,
                    recording=True)
        recorded = wire_figures(next(iter((await sim.logs()).values())), turnaround)
        await sim.clear()
        await bare_poll(sim.paths[0], settings, n, seconds)
        floor = wire_figures(next(iter((await sim.logs()).values())), turnaround)
        await sim.clear()
        await anyio.to_thread.run_sync(bare_poll_thread, sim.paths[0], settings, n, seconds)
        floor_thread = wire_figures(next(iter((await sim.logs()).values())), turnaround)
    fig = wire_figures(frames, turnaround)
    stages = stage_figures(frames, exchanges)
    async with VirtualWire(f"bench-eff-{label}-{n}") as wire:
        for s in register_slaves(n, settings, turnaround):
            wire.attach(s)

        async def clear() -> None:
            wire.clear_log()

        await _poll(SerialLine(wire.url, settings[0]), settings, n, seconds, clear)
        in_process = wire_figures(list(wire.log), turnaround)
    return BenchResult(
        "efficiency",
        f"{label} x{n}",
        {
            "efficiency": fig.efficiency,
            "gap_excess_median_us": fig.gap_median_us,
            "gap_excess_p99_us": fig.gap_p99_us,
            "violations": fig.violations + in_process.violations,
            "tps": fig.tps,
            "limit_tps": fig.limit_tps,
            "reply_to_master_us": stages.reply_to_master_us,
            "master_late_us": stages.master_late_us,
            "request_to_wire_us": stages.request_to_wire_us,
            "master_cpu_us_per_tx": cpu / max(fig.transactions, 1) * 1e6,
            "efficiency_in_process": in_process.efficiency,
            "efficiency_recording": recorded.efficiency,
            "recording_cost_points": (fig.efficiency - recorded.efficiency) * 100,
            "floor_efficiency": floor.efficiency,
            "floor_gap_excess_us": floor.gap_median_us,
            "floor_thread_efficiency": floor_thread.efficiency,
            "floor_thread_gap_excess_us": floor_thread.gap_median_us,
            "floor_violations": floor.violations + floor_thread.violations,
        },
        {
            "efficiency": at_least(EFFICIENCY_TARGET),
            "gap_excess_median_us": at_most(GAP_EXCESS_TARGET_US),
            "violations": at_most(0),
            "efficiency_in_process": at_least(EFFICIENCY_TARGET),
            "recording_cost_points": at_most(1.0),
        },
    )


async def run(opts: BenchOptions) -> list[BenchResult]:
    """2 slaves at 9600 and at 115200 (as the independent check), 8 at 115200, and 4
    slaves at four settings on one line (full: 31 at 115200 too)."""
    cases: list[tuple[str, Sequence[LineSettings], int]] = [
        ("9600 8N1", [S9600], 2),
        ("115200 8N1", [S115200], 2),
        ("115200 8N1", [S115200], 8),
        ("mixed " + "/".join(str(s.baudrate) for s in MIXED_PTY), list(MIXED_PTY), 4),
    ]
    if not opts.quick:
        cases.append(("115200 8N1", [S115200], 31))
    return [
        await efficiency(label, settings, n, opts.seconds, opts.turnaround)
        for label, settings, n in cases
    ]


SCENARIO = Scenario("efficiency", 10, run)
