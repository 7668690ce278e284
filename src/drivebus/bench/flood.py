"""Bench scenario "flood": a babbling device on one line, a healthy line polled beside it.

A device on the flooded line sends junk without pause (at the line's rate, or flat out:
as fast as the pty takes it) while 8 slaves on a second line are polled as fast as the
bus allows, a caller keeps trying the flooded line, and a heartbeat task measures how
late the event loop wakes it. Both lines' slaves and the babbler run in other processes
(the healthy line's efficiency comes from its wire log there). Reported: the loop's lag
(target: max under 50 ms), the healthy line's efficiency, how long the flooded line's
calls took to fail and with what, and how soon the flooded line worked again after the
noise stopped.
"""

from __future__ import annotations

import contextlib
import os
import time
from collections import Counter

import anyio

from drivebus.bench.common import (
    S115200,
    BenchOptions,
    BenchResult,
    Scenario,
    SimProcess,
    at_most,
    percentile,
    poll_until,
    wire_figures,
)
from drivebus.bus import Bus
from drivebus.errors import DrivebusError
from drivebus.line.serial import SerialLine
from drivebus.settings import LineSettings

__all__ = ["SCENARIO", "flood"]

LAG_TARGET_MS = 50.0
HEARTBEAT = 0.001
NOISY = LineSettings.parse("19200 8N2")
LEAST_CALLS = 3
"""Calls the flooded line's caller makes however short the run (each ends by its
timeout): on a busy machine one call took most of a 0.3 s run."""


def _like_hardware(sim: SimProcess) -> None:
    """The babbling device is hardware: CPU load on the host does not pause it. Its
    simulator process runs ahead of other work where the system allows that (a raised
    priority; as it is without the permission). Paused by load, it left silences on the
    line, and the flooded calls failed on garbled replies instead of seeing the noise."""
    with contextlib.suppress(PermissionError):
        os.setpriority(os.PRIO_PROCESS, sim.pid, -10)


async def flood(mode: str, seconds: float, turnaround: float) -> BenchResult:
    """One run: ``mode`` is "none" (the reference), "line rate" or "flat out"."""
    lags: list[float] = []
    calls: list[float] = []
    outcomes: Counter[str] = Counter()
    async with (
        SimProcess.slaves(8, [S115200], turnaround) as healthy_sim,
        SimProcess.slaves(1, [NOISY], turnaround) as noisy_sim,
        Bus(SerialLine(healthy_sim.paths[0], S115200)) as healthy,
        Bus(SerialLine(noisy_sim.paths[0], NOISY), timeout=0.1, retries=2) as noisy,
    ):
        _like_hardware(noisy_sim)
        victim = noisy.slave(1)
        await victim.read_holding_registers(0, 1)
        handles = [healthy.slave(a) for a in range(1, 9)]
        await poll_until(handles, time.monotonic() + 0.2)  # warm-up
        await healthy_sim.clear()

        async def heartbeat() -> None:
            while True:
                t = time.monotonic()
                await anyio.sleep(HEARTBEAT)
                lags.append(time.monotonic() - t - HEARTBEAT)

        async def caller(deadline: float) -> None:
            while time.monotonic() < deadline or len(calls) < LEAST_CALLS:
                t = time.monotonic()
                try:
                    await victim.read_holding_registers(0, 1)
                    outcomes["ok"] += 1
                except DrivebusError as exc:
                    outcomes[type(exc).__name__] += 1
                calls.append(time.monotonic() - t)

        c0, t0 = time.process_time(), time.monotonic()
        if mode != "none":
            await noisy_sim.babble("flat" if mode == "flat out" else "paced")
        async with anyio.create_task_group() as tg:
            tg.start_soon(heartbeat)
            async with anyio.create_task_group() as work:
                # the flooded line's caller ends its last call (bounded by its timeout)
                # rather than be cancelled in it: on a busy machine a call took most of
                # a short run, and cancelled, it was counted nowhere
                work.start_soon(caller, t0 + seconds)
                await poll_until(handles, t0 + seconds)
            tg.cancel_scope.cancel()
        noise_bytes = await noisy_sim.babble("off")
        load = (time.process_time() - c0) / (time.monotonic() - t0)
        fig = wire_figures(next(iter((await healthy_sim.logs()).values())), turnaround)
        t_quiet = time.monotonic()
        recovered_ms = float("nan")
        with anyio.move_on_after(5):
            while True:
                try:
                    await victim.read_holding_registers(0, 1)
                except DrivebusError:
                    continue
                recovered_ms = (time.monotonic() - t_quiet) * 1e3
                break
        garbage = noisy.line.garbage_bytes
        line_noise = noisy.stats.slave(1).line_noise
    lag_ms = [x * 1e3 for x in lags]
    call_ms = [x * 1e3 for x in calls]
    return BenchResult(
        "flood",
        f"{mode}, healthy 8 x {S115200}",
        {
            "max_lag_ms": max(lag_ms, default=float("nan")),
            "p99_lag_ms": percentile(lag_ms, 0.99),
            "healthy_efficiency": fig.efficiency,
            "healthy_transactions": fig.transactions,
            "healthy_violations": fig.violations,
            "flooded_calls": len(calls),
            "flooded_outcomes": ", ".join(f"{k} {v}" for k, v in sorted(outcomes.items())),
            "flooded_call_max_ms": max(call_ms, default=float("nan")),
            "line_noise": line_noise,
            "noise_bytes": noise_bytes,
            "garbage_bytes": garbage,
            "recovered_ms": recovered_ms,
            "cpu_load_cores": load,
        },
        {
            "max_lag_ms": at_most(LAG_TARGET_MS),
            "healthy_violations": at_most(0),
        },
    )


async def run(opts: BenchOptions) -> list[BenchResult]:
    """No noise (the reference), noise at the line's rate, and noise flat out."""
    return [
        await flood(mode, max(opts.seconds, 0.3), opts.turnaround)
        for mode in ("none", "line rate", "flat out")
    ]


SCENARIO = Scenario("flood", 60, run)
