"""Bench scenario "flood": a babbling device on one line, a healthy line polled beside it.

A device on the flooded line sends junk without pause (at the line's rate, or flat out:
as fast as the pty takes it) while 8 slaves on a second line are polled as fast as the
bus allows, a caller keeps trying the flooded line, and a heartbeat task measures how
late the event loop wakes it. Reported: the loop's lag (target: max under 50 ms), the
healthy line's efficiency from its wire log, how long the flooded line's calls took to
fail and with what, and how soon the flooded line worked again after the noise stopped.
"""

from __future__ import annotations

import contextlib
import time
from collections import Counter
from collections.abc import AsyncIterator

import anyio

from drivebus.bench.common import (
    S19200,
    S115200,
    BenchOptions,
    BenchResult,
    Scenario,
    percentile,
    poll_until,
    register_slaves,
    wire_figures,
)
from drivebus.bus import Bus
from drivebus.errors import DrivebusError
from drivebus.line.serial import SerialLine
from drivebus.sim.slave import RegisterSlave
from drivebus.sim.wire import VirtualWire

__all__ = ["SCENARIO", "flood"]

LAG_TARGET_MS = 50.0
HEARTBEAT = 0.001


async def flood(mode: str, seconds: float, turnaround: float) -> BenchResult:
    """One run: ``mode`` is "none" (the reference), "line rate" or "flat out"."""
    lags: list[float] = []
    calls: list[float] = []
    outcomes: Counter[str] = Counter()
    async with (
        VirtualWire(f"bench-flood-healthy-{mode}") as healthy_wire,
        VirtualWire(f"bench-flood-noisy-{mode}") as noisy_wire,
    ):
        for s in register_slaves(8, [S115200], turnaround):
            healthy_wire.attach(s)
        noisy_wire.attach(RegisterSlave(1, S19200, turnaround=turnaround))
        async with (
            Bus(SerialLine(healthy_wire.url, S115200)) as healthy,
            Bus(SerialLine(noisy_wire.url, S19200), timeout=0.1, retries=2) as noisy,
        ):
            victim = noisy.slave(1)
            await victim.read_holding_registers(0, 1)
            handles = [healthy.slave(a) for a in range(1, 9)]
            await poll_until(handles, time.monotonic() + 0.2)  # warm-up
            healthy_wire.clear_log()

            async def heartbeat() -> None:
                while True:
                    t = time.monotonic()
                    await anyio.sleep(HEARTBEAT)
                    lags.append(time.monotonic() - t - HEARTBEAT)

            async def caller(deadline: float) -> None:
                while time.monotonic() < deadline:
                    t = time.monotonic()
                    try:
                        await victim.read_holding_registers(0, 1)
                        outcomes["ok"] += 1
                    except DrivebusError as exc:
                        outcomes[type(exc).__name__] += 1
                    calls.append(time.monotonic() - t)

            c0, t0 = time.process_time(), time.monotonic()
            async with anyio.create_task_group() as tg, _noise(noisy_wire, mode):
                tg.start_soon(heartbeat)
                tg.start_soon(caller, t0 + seconds)
                await poll_until(handles, t0 + seconds)
                tg.cancel_scope.cancel()
            load = (time.process_time() - c0) / (time.monotonic() - t0)
            fig = wire_figures(list(healthy_wire.log), turnaround)
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
            "lag_target_ms": LAG_TARGET_MS,
            "healthy_efficiency": fig.efficiency,
            "healthy_transactions": fig.transactions,
            "healthy_violations": fig.violations,
            "flooded_calls": len(calls),
            "flooded_outcomes": ", ".join(f"{k} {v}" for k, v in sorted(outcomes.items())),
            "flooded_call_max_ms": max(call_ms, default=float("nan")),
            "line_noise": line_noise,
            "noise_bytes": noisy_wire.noise_bytes,
            "garbage_bytes": garbage,
            "recovered_ms": recovered_ms,
            "cpu_load_cores": load,
        },
    )


@contextlib.asynccontextmanager
async def _noise(wire: VirtualWire, mode: str) -> AsyncIterator[None]:
    if mode == "none":
        yield
        return
    async with wire.babbling(flat_out=mode == "flat out"):
        yield


async def run(opts: BenchOptions) -> list[BenchResult]:
    """No noise (the reference), noise at the line's rate, and noise flat out."""
    return [
        await flood(mode, max(opts.seconds, 0.3), opts.turnaround)
        for mode in ("none", "line rate", "flat out")
    ]


SCENARIO = Scenario("flood", 60, run)
