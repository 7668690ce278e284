"""Bench scenario "scale": many lines of moving, polled axes, in one master process or
with the lines in worker processes.

A machine of ``lines`` RS-485 lines at 115200 8N1 with 8 simulated CL86R drives each:
every axis polls as fast as its line allows (poll period 1 ms, moving or not) and moves
back and forth, all through one ``open_machine`` in this process (``workers``: its lines
served by that many worker processes, ``workers`` in the machine file). The drives run in
other processes (``SimProcess`` serving the machine file's ``sim://`` lines: as many as
the cores the master and its workers leave, at least two, ``sim_processes``), and each
line's efficiency comes from its own wire log there. Meanwhile a
stop goes to a random axis every few tens of milliseconds (a ``Priority.EMERGENCY``
write, the path of ``halt_now`` through the machine and, with workers, across to the
worker): its latency is from the call to its first byte on the wire, against the time of
one transaction of the line. Reported: the worst and mean line efficiency, gap
violations, the master's CPU in cores (the machine's process, each worker's, and per
line), the simulators' CPU, the busy cores of all of them against the host's cores (a
row whose busy cores come near the host's is limited by the machine, not by the
master), and the stop latency. A run of one line first gives the same figures with the
machine otherwise idle: the most a line gets here, against which the many-line figures
measure what sharing the cores costs.
"""

from __future__ import annotations

import contextlib
import json
import os
import random
import statistics
import tempfile
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import anyio

from drivebus.bench.common import (
    BenchOptions,
    BenchResult,
    Figure,
    Scenario,
    SimProcess,
    at_least,
    at_most,
    percentile,
    record_exchanges,
    stage_figures,
    wire_figures,
)
from drivebus.bus import Bus, Priority
from drivebus.errors import DrivebusError, ModbusException
from drivebus.motion import open_machine
from drivebus.motion.workers import auto_workers
from drivebus.settings import LineSettings
from drivebus.timing import timing

__all__ = ["EFFICIENCY_TARGET", "SCENARIO", "machine_mapping", "scale", "sim_processes"]

EFFICIENCY_TARGET = 0.95
SETTINGS = "115200 8N1"
TURNAROUND = 0.001
SIM_PROCESSES = int(os.environ.get("DRIVEBUS_BENCH_SIM_PROCESSES", "0")) or None
"""Simulator processes for the drives (default: ``sim_processes``)."""


def sim_processes(lines: int, workers: int, cores: int | None = None) -> int:
    """How many simulator processes serve a row's drives: the cores the master and its
    workers leave (one each), at least two and at most one per line. On a small machine
    the drives share the master's cores; on a large one they get cores of their own, so
    that a late reply is the master's doing, not the simulated drives'."""
    cores = (os.cpu_count() or 1) if cores is None else cores
    return max(min(2, lines), min(lines, cores - 1 - workers))


def machine_mapping(lines: int, axes: int, port: Callable[[int], str], workers: int = 0
                    ) -> dict[str, Any]:
    """The bench machine: ``lines`` lines (``port(i)`` for line i) of ``axes`` CL86R axes,
    served by ``workers`` worker processes (0: by the machine's own)."""
    cfg: dict[str, Any] = {"name": "bench-scale", "lines": {}, "axes": {},
                           "workers": workers}
    for i in range(lines):
        cfg["lines"][f"l{i}"] = {"port": port(i), "settings": SETTINGS}
        for a in range(1, axes + 1):
            cfg["axes"][f"a{i}_{a}"] = {
                "line": f"l{i}", "address": a, "drive": "CL86R", "settings": SETTINGS,
                "pulses_per_rev": 1000, "units_per_rev": 5.0,
                "speed": 200.0, "accel": 2000.0, "decel": 2000.0,
                "poll": {"moving": 0.001, "idle": 0.001},
                "sim": {"turnaround": TURNAROUND},
            }
    return cfg


@contextlib.contextmanager
def _sim_files(lines: int, axes: int, processes: int) -> Iterator[list[Path]]:
    """The machine's simulated half, as one JSON machine file per simulator process."""
    full = machine_mapping(lines, axes, lambda i: f"sim://bench-scale-{i}")
    paths = []
    try:
        for p in range(processes):
            mine = {f"l{i}" for i in range(lines) if i % processes == p}
            part = dict(full, lines={k: v for k, v in full["lines"].items() if k in mine},
                        axes={k: v for k, v in full["axes"].items() if v["line"] in mine})
            fd, name = tempfile.mkstemp(prefix="drivebus-bench-", suffix=".json")
            with os.fdopen(fd, "w") as f:
                json.dump(part, f)
            paths.append(Path(name))
        yield paths
    finally:
        for p in paths:
            p.unlink(missing_ok=True)


STOP_REGISTER = 0x7FF0
"""The register the bench's stops write (the CL86R has none there: each is answered with
an exception, after its frame has been on the wire, which is all that is measured)."""


def process_cpu(pid: int) -> float:
    """CPU seconds (user + system) of process ``pid`` so far; NaN where /proc cannot say."""
    try:
        with open(f"/proc/{pid}/stat") as f:
            fields = f.read().rpartition(")")[2].split()
        return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")
    except (OSError, ValueError, IndexError):
        return float("nan")


async def scale(lines: int, axes: int, seconds: float, workers: int = 0) -> BenchResult:
    """``lines`` x ``axes`` moving, polled axes; the drives in other processes, the lines
    in ``workers`` worker processes (0: in this one)."""
    moves = failed = 0
    called: dict[int, float] = {}
    sim_count = SIM_PROCESSES or sim_processes(lines, workers)
    with _sim_files(lines, axes, sim_count) as files:
        async with contextlib.AsyncExitStack() as stack:
            sims = [await stack.enter_async_context(SimProcess("--machine", str(f)))
                    for f in files]
            where: dict[str, str] = {}
            for s in sims:
                where.update(json.loads(s.first_line))
            mapping = machine_mapping(lines, axes, lambda i: where[f"l{i}"], workers)
            async with open_machine(mapping) as m:
                for ax in m.axes.values():
                    await ax.enable()
                exchanges = {name: record_exchanges(bus.line) for name, bus in m.buses.items()
                             if isinstance(bus, Bus)}
                pids = [w["pid"] for w in m.workers]
                for s in sims:
                    await s.clear()
                    await s.logs()  # its CPU time so far
                sim_cpu0 = sum(s.cpu for s in sims)
                deadline = time.monotonic() + seconds

                async def mover(ax: Any) -> None:
                    nonlocal moves, failed
                    target = 20.0
                    while time.monotonic() < deadline:
                        try:
                            await ax.move_to(target)
                        except DrivebusError:  # an overloaded host: counted, not fatal
                            failed += 1
                            await anyio.sleep(0.05)
                            continue
                        target = 20.0 - target
                        moves += 1

                async def stopper() -> None:
                    rng = random.Random(37)
                    handles = [m.buses[a.config.line].slave(a.config.address)
                               for a in m.axes.values()]
                    i = 0
                    while time.monotonic() < deadline - 0.05:
                        await anyio.sleep(rng.uniform(0.01, 0.05))
                        called[i] = time.monotonic()
                        with contextlib.suppress(ModbusException):
                            await rng.choice(handles).write_register(
                                STOP_REGISTER, i, priority=Priority.EMERGENCY)
                        i += 1

                c0, t0 = time.process_time(), time.monotonic()
                w0 = [process_cpu(pid) for pid in pids if pid is not None]
                async with anyio.create_task_group() as tg:
                    for ax in m.axes.values():
                        tg.start_soon(mover, ax)
                    tg.start_soon(stopper)
                wall = time.monotonic() - t0
                cores = (time.process_time() - c0) / wall
                worker_cores = [(process_cpu(pid) - c) / wall
                                for pid, c in zip((p for p in pids if p is not None), w0,
                                                  strict=True)]
            logs: dict[str, Any] = {}
            for s in sims:
                logs.update(await s.logs())
            sim_cores = (sum(s.cpu for s in sims) - sim_cpu0) / wall
    figs = [wire_figures(frames, TURNAROUND) for frames in logs.values()]
    effs = [f.efficiency for f in figs]
    stages = [stage_figures(frames, exchanges[name]) for name, frames in logs.items()
              if name in exchanges]
    stops = [f.start - called[int.from_bytes(f.data[4:6], "big")]
             for frames in logs.values() for f in frames
             if f.direction == "request" and f.data[1] == 0x06
             and int.from_bytes(f.data[2:4], "big") == STOP_REGISTER
             and int.from_bytes(f.data[4:6], "big") in called]
    tm = timing(LineSettings.parse(SETTINGS))
    poll_tx = tm.transaction_time(8, 25, TURNAROUND)  # a 10-register status read

    def med(values: list[float]) -> float:
        return statistics.median(values) if values else float("nan")

    total_cores = cores + sum(worker_cores)
    figures: dict[str, Figure] = {
        "eff_min": min(effs),
        "eff_mean": statistics.mean(effs),
        "gap_excess_median_us": statistics.median(f.gap_median_us for f in figs),
        "reply_to_master_us": med([st.reply_to_master_us for st in stages]),
        "master_late_us": med([st.master_late_us for st in stages]),
        "request_to_wire_us": med([st.request_to_wire_us for st in stages]),
        "violations": sum(f.violations for f in figs),
        "transactions": sum(f.transactions for f in figs),
        "moves": moves,
        "failed_moves": failed,
        "master_cpu_cores": cores,
        "worker_cpu_cores": ",".join(f"{c:.2f}" for c in worker_cores) or "-",
        "cpu_per_line": total_cores / lines,
        "sim_cpu_cores": sim_cores,
        "sim_processes": sim_count,
        "host_cores": os.cpu_count() or 1,
        "busy_cores": total_cores + sim_cores,
        "stops": len(stops),
        "stop_p99_ms": percentile(stops, 0.99) * 1e3,
        "stop_max_ms": max(stops) * 1e3 if stops else float("nan"),
        "stop_p99_in_tx": percentile(stops, 0.99) / poll_tx,
    }
    return BenchResult(
        "scale",
        f"{lines} lines x {axes} axes, {SETTINGS}, "
        + (f"{workers} worker{'s' if workers > 1 else ''}" if workers else "one process"),
        figures,
        {"eff_min": at_least(EFFICIENCY_TARGET), "violations": at_most(0),
         "stop_p99_in_tx": at_most(STOP_TARGET)},
    )


STOP_TARGET = 1 + timing(LineSettings.parse(SETTINGS)).t35 / timing(
    LineSettings.parse(SETTINGS)).transaction_time(8, 25, TURNAROUND)
"""A stop's first byte within the transaction in flight and its silence (p99), in
transactions of the line."""

WORKERS = int(os.environ.get("DRIVEBUS_BENCH_WORKERS", "0")) or None
"""Worker processes for the many-line row with workers (default: ``workers = "auto"``'s
count for its lines on this machine, at least one)."""


async def run(opts: BenchOptions) -> list[BenchResult]:
    """1 line x 8 axes, the same line with nothing else on the machine (what a line gets
    when no other competes for the cores), 4 lines x 8 axes, then 16 lines x 8 axes in one
    process and with worker processes (quick: 1 x 8, 4 x 8, and 4 x 8 with one worker)."""
    many = 4 if opts.quick else 16
    workers = WORKERS or max(1, auto_workers(many))
    cases = [(1, 0), (4, 0)] + ([] if opts.quick else [(16, 0)]) + [(many, workers)]
    return [await scale(lines, 8, opts.seconds, w) for lines, w in cases]


SCENARIO = Scenario("scale", 40, run)
