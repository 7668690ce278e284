"""Bench scenario "pipelined tcp": drivebus with 1 and 8 requests in flight against pymodbus.

The server is pymodbus's own Modbus TCP server, in a process of its own on loopback; 16
callers read 4 holding registers of unit 1 as fast as they can, through one connection:
drivebus's ``Bus`` on a ``TcpLine`` with ``max_in_flight`` 1 and 8, and pymodbus's
``AsyncModbusTcpClient`` (one request at a time per client). Reported: transactions per
second (each client's best of its rounds, taken in turns), the master's CPU per
transaction, and each figure against pymodbus's.
"""

from __future__ import annotations

import logging
import time

import anyio

from drivebus.bench.common import BenchOptions, BenchResult, ChildProcess, Scenario, at_least
from drivebus.bus import Bus, Priority
from drivebus.line.tcp import TcpLine

__all__ = ["SCENARIO", "pipelined_tcp"]

CALLERS = 16
REGISTERS = 4


async def _drivebus(port: int, in_flight: int, seconds: float) -> tuple[float, float]:
    async with Bus(TcpLine("127.0.0.1", port, max_in_flight=in_flight), timeout=1.0) as bus:
        h = bus.slave(1)
        return await _callers(
            lambda: h.read_holding_registers(0, REGISTERS, priority=Priority.POLL), seconds
        )


async def _pymodbus(port: int, seconds: float) -> tuple[float, float]:
    from pymodbus.client import AsyncModbusTcpClient

    logging.getLogger("pymodbus").setLevel(logging.CRITICAL)
    client = AsyncModbusTcpClient("127.0.0.1", port=port, timeout=1.0, retries=0)
    await client.connect()
    try:
        return await _callers(
            lambda: client.read_holding_registers(0, count=REGISTERS, device_id=1), seconds
        )
    finally:
        client.close()


async def _callers(read: object, seconds: float) -> tuple[float, float]:
    """Run ``CALLERS`` tasks calling ``read()`` for a warm-up, then ``seconds``: the
    transactions per second and the CPU µs per transaction of this process."""
    done = 0
    counting = False

    async def caller(deadline: float) -> None:
        nonlocal done
        while time.monotonic() < deadline:
            await read()  # type: ignore[operator]
            if counting:
                done += 1

    async def run(d: float) -> None:
        deadline = time.monotonic() + d
        async with anyio.create_task_group() as tg:
            for _ in range(CALLERS):
                tg.start_soon(caller, deadline)

    await run(0.2)
    counting = True
    c0, t0 = time.process_time(), time.monotonic()
    await run(seconds)
    cpu, wall = time.process_time() - c0, time.monotonic() - t0
    return done / wall, cpu / max(done, 1) * 1e6


async def pipelined_tcp(seconds: float, rounds: int = 2) -> list[BenchResult]:
    """The three clients in turn on the same server and workload, ``rounds`` times (A B C
    A B C ...); each one's best round is reported (the least disturbed by other load)."""
    runs: dict[str, list[tuple[float, float]]] = {"1": [], "8": [], "pymodbus": []}
    async with ChildProcess("drivebus.bench.pymodbus_server") as server:
        port = int(server.first_line)
        for _ in range(rounds):
            runs["1"].append(await _drivebus(port, 1, seconds))
            runs["8"].append(await _drivebus(port, 8, seconds))
            runs["pymodbus"].append(await _pymodbus(port, seconds))
    one, eight, theirs = (max(runs[k]) for k in ("1", "8", "pymodbus"))
    rows = []
    for case, (tps, cpu) in (("drivebus, 1 in flight", one), ("drivebus, 8 in flight", eight),
                             ("pymodbus AsyncModbusTcpClient", theirs)):
        figures = {"tps": tps, "cpu_us_per_tx": cpu, "tps_vs_pymodbus": tps / theirs[0],
                   "tps_vs_drivebus_1": tps / one[0]}
        targets = {} if case.startswith("pymodbus") else {"tps_vs_pymodbus": at_least(1.0)}
        rows.append(BenchResult("pipelined tcp", f"{case}, {CALLERS} callers", figures,
                                targets))
    return rows


async def run(opts: BenchOptions) -> list[BenchResult]:
    """Two rounds of each client (quick: one)."""
    return await pipelined_tcp(opts.seconds, 1 if opts.quick else 2)


SCENARIO = Scenario("pipelined tcp", 55, run)
