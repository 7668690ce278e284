"""Bench scenario "efficiency": slaves polled as fast as the bus allows, against the wire limit.

The slaves run in another process (``SimProcess``) and the figures come from its wire log:
what the wire saw, on the same clock as the master, with nothing of the simulator in the
master's event loop or CPU time. The same run with the simulator in the master's process
is the second column (``efficiency_in_process``). The stages split the silence between a
reply and the next request: the reply reaching the master, the master's own lateness, and
the request reaching the wire.
"""

from __future__ import annotations

import time
from collections.abc import Sequence

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
from drivebus.bus import Bus
from drivebus.line.serial import SerialLine
from drivebus.settings import LineSettings
from drivebus.sim.wire import VirtualWire

__all__ = ["EFFICIENCY_TARGET", "GAP_EXCESS_TARGET_US", "SCENARIO", "efficiency"]

EFFICIENCY_TARGET = 0.97
GAP_EXCESS_TARGET_US = 150.0
REGISTERS = 4
"""Registers per read: a drive's status block."""


async def _poll(line: SerialLine, settings: Sequence[LineSettings], n: int, seconds: float,
                clear: object) -> tuple[float, list]:
    async with Bus(line) as bus:
        handles = [bus.slave(a, settings=settings[(a - 1) % len(settings)])
                   for a in range(1, n + 1)]
        await poll_until(handles, time.monotonic() + 0.2, registers=REGISTERS)  # warm-up
        await clear()  # type: ignore[operator]
        exchanges = record_exchanges(line)
        c0 = time.process_time()
        await poll_until(handles, time.monotonic() + seconds, registers=REGISTERS)
        return time.process_time() - c0, exchanges


async def efficiency(
    label: str, settings: Sequence[LineSettings], n: int, seconds: float, turnaround: float
) -> BenchResult:
    """``n`` slaves (settings taken in turn) polled as fast as the bus allows, the slaves
    in another process; then the same with them in this one."""
    async with SimProcess.slaves(n, settings, turnaround) as sim:
        cpu, exchanges = await _poll(SerialLine(sim.paths[0], settings[0]), settings, n,
                                     seconds, sim.clear)
        frames = next(iter((await sim.logs()).values()))
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
        },
        {
            "efficiency": at_least(EFFICIENCY_TARGET),
            "gap_excess_median_us": at_most(GAP_EXCESS_TARGET_US),
            "violations": at_most(0),
            "efficiency_in_process": at_least(EFFICIENCY_TARGET),
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
