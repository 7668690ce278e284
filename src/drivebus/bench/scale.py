"""Bench scenario "scale": many lines of moving, polled axes in one master process.

A machine of ``lines`` RS-485 lines at 115200 8N1 with 8 simulated CL86R drives each:
every axis polls as fast as its line allows (poll period 1 ms, moving or not) and moves
back and forth, all through one ``open_machine`` in this process. The drives run in
other processes (``SimProcess`` serving the machine file's ``sim://`` lines, half the
lines each), and each line's efficiency comes from its own wire log there. Reported: the
worst and mean line efficiency, gap violations, and the master's CPU in cores. A run
of one line first gives the same figures with the machine otherwise idle: the most a
line gets here, against which the many-line figures measure what sharing the cores costs.
"""

from __future__ import annotations

import contextlib
import json
import os
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
    Scenario,
    SimProcess,
    at_least,
    at_most,
    record_exchanges,
    stage_figures,
    wire_figures,
)
from drivebus.motion import open_machine

__all__ = ["EFFICIENCY_TARGET", "SCENARIO", "machine_mapping", "scale"]

EFFICIENCY_TARGET = 0.95
SETTINGS = "115200 8N1"
TURNAROUND = 0.001
SIM_PROCESSES = int(os.environ.get("DRIVEBUS_BENCH_SIM_PROCESSES", "2"))


def machine_mapping(lines: int, axes: int, port: Callable[[int], str]) -> dict[str, Any]:
    """The bench machine: ``lines`` lines (``port(i)`` for line i) of ``axes`` CL86R axes."""
    cfg: dict[str, Any] = {"name": "bench-scale", "lines": {}, "axes": {}}
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
def _sim_files(lines: int, axes: int) -> Iterator[list[Path]]:
    """The machine's simulated half, as one JSON machine file per simulator process."""
    full = machine_mapping(lines, axes, lambda i: f"sim://bench-scale-{i}")
    paths = []
    try:
        for p in range(SIM_PROCESSES):
            mine = {f"l{i}" for i in range(lines) if i % SIM_PROCESSES == p}
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


async def scale(lines: int, axes: int, seconds: float) -> BenchResult:
    """``lines`` x ``axes`` moving, polled axes; the drives in other processes."""
    moves = 0
    with _sim_files(lines, axes) as files:
        async with contextlib.AsyncExitStack() as stack:
            sims = [await stack.enter_async_context(SimProcess("--machine", str(f)))
                    for f in files]
            where: dict[str, str] = {}
            for s in sims:
                where.update(json.loads(s.first_line))
            async with open_machine(machine_mapping(lines, axes, lambda i: where[f"l{i}"])) as m:
                for ax in m.axes.values():
                    await ax.enable()
                exchanges = {name: record_exchanges(bus.line) for name, bus in m.buses.items()}
                for s in sims:
                    await s.clear()
                    await s.logs()  # its CPU time so far
                sim_cpu0 = sum(s.cpu for s in sims)
                deadline = time.monotonic() + seconds

                async def mover(ax: Any) -> None:
                    nonlocal moves
                    target = 20.0
                    while time.monotonic() < deadline:
                        await ax.move_to(target)
                        target = 20.0 - target
                        moves += 1

                c0, t0 = time.process_time(), time.monotonic()
                async with anyio.create_task_group() as tg:
                    for ax in m.axes.values():
                        tg.start_soon(mover, ax)
                wall = time.monotonic() - t0
                cores = (time.process_time() - c0) / wall
            logs: dict[str, Any] = {}
            for s in sims:
                logs.update(await s.logs())
            sim_cores = (sum(s.cpu for s in sims) - sim_cpu0) / wall
    figs = [wire_figures(frames, TURNAROUND) for frames in logs.values()]
    effs = [f.efficiency for f in figs]
    stages = [stage_figures(frames, exchanges[name]) for name, frames in logs.items()]
    return BenchResult(
        "scale",
        f"{lines} lines x {axes} axes, {SETTINGS}",
        {
            "eff_min": min(effs),
            "eff_mean": statistics.mean(effs),
            "gap_excess_median_us": statistics.median(f.gap_median_us for f in figs),
            "reply_to_master_us": statistics.median(st.reply_to_master_us for st in stages),
            "master_late_us": statistics.median(st.master_late_us for st in stages),
            "request_to_wire_us": statistics.median(st.request_to_wire_us for st in stages),
            "violations": sum(f.violations for f in figs),
            "transactions": sum(f.transactions for f in figs),
            "moves": moves,
            "master_cpu_cores": cores,
            "sim_cpu_cores": sim_cores,
        },
        {"eff_min": at_least(EFFICIENCY_TARGET), "violations": at_most(0)},
    )


async def run(opts: BenchOptions) -> list[BenchResult]:
    """1 line x 8 axes, the same line with nothing else on the machine (what a line gets
    when no other competes for the cores), then 16 lines x 8 axes (quick: 4 x 8)."""
    return [await scale(lines, 8, opts.seconds) for lines in (1, 4 if opts.quick else 16)]


SCENARIO = Scenario("scale", 40, run)
