"""Bench scenario "stop during planning": a stop issued while group moves and paths are
planned and started on the same line, and what planning costs.

On the demo machine (twins in this process, one clock): z jogs on the RS-485 line while
a 3-axis group move (x, y on that line, r on TCP) or a 2-axis path of x and y is
started; a random moment (0-30 ms) into it, ``z.stop()`` is called. Latency is from the
call to the first byte of z's stop frame on the simulated wire. Target: p99 within one
transaction of the line at its slowest setting plus 5 ms. Also the CPU (thread time) a
4-axis group plan takes per axis, and the longest event-loop step of the run.
"""

from __future__ import annotations

import contextlib
import random
import time

import anyio

from drivebus.bench.common import BenchOptions, BenchResult, Scenario, at_most, percentile
from drivebus.bench.motion import DEMO
from drivebus.errors import GroupMotionError, MotionAborted
from drivebus.motion import Machine, open_machine
from drivebus.timing import timing

__all__ = ["SCENARIO", "stop_during_planning"]

_STOP_REPLY = 8  # an FC06 request and its echo, bytes
_LONGEST_REPLY = 25  # the longest status reply on the demo's RS-485 line, bytes


def _z_stop_frames(m: Machine, since: int) -> list[float]:
    """Start times of the CL86R's (z, address 4) stop frames on the RS-485 wire."""
    out = []
    for f in list(m.wires["rs485"].log)[since:]:
        d = f.data
        if (f.direction == "request" and f.address == 4 and len(d) >= 8 and d[1] == 0x06
                and int.from_bytes(d[2:4], "big") == 0x36 and d[5] & 0x60):
            out.append(f.start)
    return out


def _line_transaction(m: Machine) -> float:
    """The longest transaction of the RS-485 line: its slowest slave's status read."""
    slowest = min((a.profile.slave.settings or m.buses["rs485"].line.settings
                   for a in m.axes.values() if a.config.line == "rs485"),
                  key=lambda s: s.baudrate)
    return timing(slowest).transaction_time(_STOP_REPLY, _LONGEST_REPLY, 0.001)


async def _plan_cpu(m: Machine) -> float:
    """Thread CPU seconds per axis of planning a 4-axis group move (fits not remembered)."""
    for ax in m.axes.values():
        ax.__dict__.pop("_fits", None)
    g = m.group("x", "y", "z", "r")
    starts = {n: m.axes[n].position or 0.0 for n in g.axes}
    targets = {"x": 150.0, "y": 90.0, "z": 60.0, "r": 270.0}
    started = time.thread_time()
    await g._plan(targets, starts)
    return (time.thread_time() - started) / len(targets)


async def stop_during_planning(rounds: int) -> BenchResult:
    """``rounds`` stops of a jogging z, half during group moves, half during paths."""
    rng = random.Random(3)
    latencies: list[float] = []
    async with open_machine(DEMO) as m:
        z = m.axes["z"]
        plan_cpu = await _plan_cpu(m)
        for i in range(rounds):
            lo = i % 2 == 0
            xy = {"x": 40.0 if lo else 160.0, "y": 30.0 if lo else 100.0}
            r = 90.0 if lo else 270.0

            async def command(xy: dict[str, float] = xy, r: float = r,
                              path: bool = i % 4 >= 2) -> None:
                with contextlib.suppress(MotionAborted, GroupMotionError):
                    if path:
                        await m.group("x", "y").path(
                            [{"x": xy["x"]}, {"y": xy["y"]}, {"x": xy["x"] + 5.0}])
                    else:
                        await m.group("x", "y", "r").move_to(
                            {**xy, "r": r})

            await z.jog(4.0 if (z.position or 0.0) < 50 else -4.0, watchdog=None)
            mark = len(m.wires["rs485"].log)
            async with anyio.create_task_group() as tg:
                tg.start_soon(command)
                await anyio.sleep(rng.uniform(0.0, 0.03))
                called = time.monotonic()
                await z.stop()
                stops = [t for t in _z_stop_frames(m, mark) if t >= called]
                if stops:
                    latencies.append(stops[0] - called)
        tx = _line_transaction(m)
    us = [x * 1e6 for x in latencies]
    return BenchResult(
        "stop during planning", "demo, z stopped while x/y/r plan and start",
        {
            "stops": len(us),
            "p50_us": percentile(us, 0.5),
            "p99_us": percentile(us, 0.99),
            "max_us": max(us, default=float("nan")),
            "transaction_us": tx * 1e6,
            "plan_cpu_ms_per_axis": plan_cpu * 1e3,
        },
        {"p99_us": at_most((tx + 0.005) * 1e6), "plan_cpu_ms_per_axis": at_most(20.0)},
    )


async def run(opts: BenchOptions) -> list[BenchResult]:
    """40 stops (quick: 12)."""
    return [await stop_during_planning(12 if opts.quick else 40)]


SCENARIO = Scenario("stop during planning", 25, run)
