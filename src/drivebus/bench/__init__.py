"""drivebus bench: bus efficiency against the wire limit, stop latency, CPU, scale, baseline.

Every scenario runs on simulated lines (wire time emulated, slave turnaround default 1 ms)
and is measured from the simulator's wire log, not from the master's own bookkeeping.
"""

from __future__ import annotations

import asyncio
import contextlib
import itertools
import json
import logging
import os
import random
import statistics
import subprocess
import sys
import time
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from dataclasses import asdict, dataclass, field

import anyio
import serial

from drivebus.bus import Bus, Priority, SlaveHandle
from drivebus.clock import PreciseTimer
from drivebus.line.rtu import frame as rtu_frame
from drivebus.line.serial import SerialLine
from drivebus.settings import LineSettings
from drivebus.sim.slave import RegisterSlave
from drivebus.sim.wire import VirtualWire, WireFrame
from drivebus.timing import timing

__all__ = ["run_bench"]

S9600 = LineSettings.parse("9600 8N1")
S19200 = LineSettings.parse("19200 8E1")
S38400 = LineSettings.parse("38400 8N2")
S115200 = LineSettings.parse("115200 8N1")
MIXED = (S9600, S19200, S38400, S115200)


def _pct(values: Sequence[float], q: float) -> float:
    if not values:
        return float("nan")
    s = sorted(values)
    return s[min(len(s) - 1, int(q * (len(s) - 1) + 0.5))]


@dataclass
class WireFigures:
    """What the wire log says about one run."""

    transactions: int
    tps: float
    limit_tps: float
    efficiency: float
    gap_median_us: float
    gap_p99_us: float
    gap_max_us: float
    violations: int


def wire_figures(frames: Sequence[WireFrame], turnaround: float) -> WireFigures:
    """Achieved against ideal timing for the request/reply pairs in ``frames``."""
    pairs: list[tuple[WireFrame, WireFrame]] = []
    pending: WireFrame | None = None
    for f in frames:
        if f.direction == "request":
            pending = f
        elif pending is not None:
            pairs.append((pending, f))
            pending = None
    actual = ideal = 0.0
    excess: list[float] = []
    for (req, rep), (nxt, _) in itertools.pairwise(pairs):
        actual += nxt.start - req.start
        tm = timing(req.settings)
        ideal += tm.frame_time(len(req.data) + len(rep.data)) + turnaround + nxt.required
        excess.append((nxt.gap - nxt.required) * 1e6)
    n = len(pairs) - 1
    violations = sum(1 for f in frames if f.direction == "request" and f.violation)
    return WireFigures(
        transactions=len(pairs),
        tps=n / actual if actual else 0.0,
        limit_tps=n / ideal if ideal else 0.0,
        efficiency=ideal / actual if actual else 0.0,
        gap_median_us=statistics.median(excess) if excess else float("nan"),
        gap_p99_us=_pct(excess, 0.99),
        gap_max_us=max(excess) if excess else float("nan"),
        violations=violations,
    )


@dataclass
class BenchResult:
    """One row of the bench's table."""

    scenario: str
    case: str
    figures: dict[str, float | int | str] = field(default_factory=dict)


async def _poll_until(handles: Sequence[SlaveHandle], deadline: float, per_slave: int = 1) -> None:
    async def poller(h: SlaveHandle) -> None:
        while time.monotonic() < deadline:
            await h.read_holding_registers(0, 2, priority=Priority.POLL)

    async with anyio.create_task_group() as tg:
        for h in handles:
            for _ in range(per_slave):
                tg.start_soon(poller, h)


def _slaves(n: int, settings: Sequence[LineSettings], turnaround: float) -> list[RegisterSlave]:
    return [
        RegisterSlave(a, settings[(a - 1) % len(settings)], size=16, turnaround=turnaround)
        for a in range(1, n + 1)
    ]


async def efficiency(
    label: str, settings: Sequence[LineSettings], n: int, seconds: float, turnaround: float
) -> BenchResult:
    """Scenario 1: ``n`` slaves polled as fast as the bus allows."""
    slaves = _slaves(n, settings, turnaround)
    async with VirtualWire(f"bench-eff-{label}-{n}") as wire:
        for s in slaves:
            wire.attach(s)
        async with Bus(SerialLine(wire.url, settings[0])) as bus:
            handles = [bus.slave(s.address, settings=s.settings) for s in slaves]
            await _poll_until(handles, time.monotonic() + 0.2)  # warm-up
            wire.clear_log()
            c0 = time.process_time()
            await _poll_until(handles, time.monotonic() + seconds)
            cpu = time.process_time() - c0
        fig = wire_figures(list(wire.log), turnaround)
    row = asdict(fig)
    row["cpu_us_per_tx_incl_sim"] = cpu / max(fig.transactions, 1) * 1e6
    return BenchResult("efficiency", f"{label} x{n}", row)


async def stop_latency(settings: LineSettings, stops: int, turnaround: float) -> BenchResult:
    """Scenario 2: emergency writes into a line saturated by polls from 8 axes."""
    slaves = _slaves(8, [settings], turnaround)
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
                tg.start_soon(_poll_until, handles, done, 2)
                tg.start_soon(stopper, tg)
    tm = timing(settings)
    tx = tm.transaction_time(8, 9, turnaround)
    us = [x * 1e6 for x in lat]
    return BenchResult(
        "stop latency",
        f"{settings} 8 axes",
        {
            "stops": len(lat),
            "p50_us": _pct(us, 0.5),
            "p99_us": _pct(us, 0.99),
            "max_us": max(us),
            "transaction_us": tx * 1e6,
            "p99_in_transactions": _pct(us, 0.99) / (tx * 1e6),
            "target_us": (tx + tm.t35) * 1e6,
        },
    )


@contextmanager
def _wire_in_process(slaves: int, settings: LineSettings, turnaround: float) -> Iterator[str]:
    """A simulated wire in a child process; yields the pty path to open."""
    proc = subprocess.Popen(
        [sys.executable, "-m", "drivebus.sim.process", "--slaves", str(slaves),
         "--settings", str(settings), "--turnaround", str(turnaround)],
        stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True,
    )
    try:
        assert proc.stdout is not None
        yield proc.stdout.readline().strip()
    finally:
        proc.communicate(timeout=10)


async def cpu_per_transaction(seconds: float) -> BenchResult:
    """Scenario 3: the master stack's own CPU per transaction, the wire out of the way.

    The simulated wire runs in a child process so this process's CPU time is the
    stack's alone: scheduler, line, framing, timers and the event loop.
    """
    fast = LineSettings(baudrate=4_000_000, parity="N")
    with _wire_in_process(1, fast, 0.0) as path:
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
        floor = await _round_trip_floor(path, fast, seconds)
    return BenchResult(
        "cpu",
        "4 Mbaud, turnaround 0",
        {"transactions": n, "tps": n / wall, "master_cpu_us_per_tx": cpu / n * 1e6,
         "floor_cpu_us_per_tx": floor},
    )


async def _round_trip_floor(path: str, settings: LineSettings, seconds: float) -> float:
    """CPU per round trip of the bare minimum on this machine: one precise timer wait,
    one write and one read wake-up on the same pty, no drivebus layers. It is the floor
    under scenario 3 that only a faster machine or interpreter can lower."""
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


async def scale(lines: int, axes: int, seconds: float, turnaround: float) -> BenchResult:
    """Scenario 4: many lines with many slaves each, all polling, in one process."""
    settings = S115200
    effs: list[float] = []
    viol = 0
    async with contextlib.AsyncExitStack() as stack:
        wires = []
        buses = []
        for i in range(lines):
            wire = await stack.enter_async_context(VirtualWire(f"bench-scale-{i}"))
            for s in _slaves(axes, [settings], turnaround):
                wire.attach(s)
            bus = await stack.enter_async_context(Bus(SerialLine(wire.url, settings)))
            wires.append(wire)
            buses.append(bus)
        c0, t0 = time.process_time(), time.monotonic()
        async with anyio.create_task_group() as tg:
            for bus in buses:
                tg.start_soon(_poll_until, [bus.slave(a) for a in range(1, axes + 1)],
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


async def pymodbus_baseline(
    label: str, settings: LineSettings, n: int, seconds: float, turnaround: float, *,
    strict: bool,
) -> BenchResult:
    """Scenario 5: the same polling with pymodbus's own async serial client.

    ``strict``: the simulated slaves lose a frame sent without the t3.5 silence, as the
    spec's state machine does; otherwise they answer it anyway (many real slaves do) and
    the violation is only counted.
    """
    from pymodbus.client import AsyncModbusSerialClient
    from pymodbus.exceptions import ModbusIOException

    logging.getLogger("pymodbus").setLevel(logging.CRITICAL)  # it logs every lost reply
    slaves = _slaves(n, [settings], turnaround)
    kind = "strict" if strict else "lenient"
    async with VirtualWire(f"bench-pymodbus-{label}-{n}-{kind}", strict=strict) as wire:
        for s in slaves:
            wire.attach(s)
        client = AsyncModbusSerialClient(
            port=wire.url, baudrate=settings.baudrate, bytesize=settings.bytesize,
            parity=settings.parity, stopbits=settings.stopbits, timeout=0.1, retries=0,
        )
        await client.connect()
        failed = 0

        async def read(unit: int) -> None:
            nonlocal failed
            try:
                await client.read_holding_registers(0, count=2, device_id=unit)
            except ModbusIOException:
                failed += 1  # the slave lost the frame (e.g. sent without the silence)

        try:
            deadline = time.monotonic() + 0.2
            while time.monotonic() < deadline:
                await read(1)
            wire.clear_log()
            failed = 0
            c0 = time.process_time()
            deadline = time.monotonic() + seconds
            i = 0
            while time.monotonic() < deadline:
                await read(i % n + 1)
                i += 1
            cpu = time.process_time() - c0
        finally:
            client.close()
        fig = wire_figures(list(wire.log), turnaround)
    row = asdict(fig)
    row["failed_requests"] = failed
    row["cpu_us_per_tx_incl_sim"] = cpu / max(fig.transactions, 1) * 1e6
    return BenchResult("pymodbus baseline", f"{label} x{n} {kind} slaves", row)


async def run_bench(
    *, quick: bool = False, turnaround: float = 0.001, seconds: float | None = None
) -> list[BenchResult]:
    """Run every scenario; ``quick`` shortens them, ``seconds`` sets each run's length."""
    secs = seconds or (0.6 if quick else 3.0)
    results: list[BenchResult] = []
    cases = [("9600 8N1", [S9600]), ("19200 8E1", [S19200]), ("115200 8N1", [S115200]),
             ("mixed", list(MIXED))]
    counts = (1, 8) if quick else (1, 8, 31)
    for label, settings in cases:
        for n in counts:
            results.append(await efficiency(label, settings, n, secs, turnaround))
    for s in ((S115200,) if quick else (S19200, S115200)):
        results.append(await stop_latency(s, 20 if quick else 200, turnaround))
    results.append(await cpu_per_transaction(secs))
    results.append(await scale(4 if quick else 16, 8, secs, turnaround))
    for label, s in (("19200 8E1", S19200), ("115200 8N1", S115200)):
        for strict in (True, False):
            results.append(await pymodbus_baseline(label, s, 8, secs, turnaround, strict=strict))
    return results


def results_json(results: Sequence[BenchResult]) -> str:
    """The results as JSON text."""
    return json.dumps([asdict(r) for r in results], indent=2)


def format_table(results: Sequence[BenchResult]) -> str:
    """The results as a plain-text table, one scenario per block."""
    lines: list[str] = []
    last = None
    for r in results:
        if r.scenario != last:
            lines.append(f"\n== {r.scenario}")
            last = r.scenario
        cells = ", ".join(
            f"{k}={v:.3f}" if isinstance(v, float) else f"{k}={v}" for k, v in r.figures.items()
        )
        lines.append(f"  {r.case:<28} {cells}")
    return "\n".join(lines)
