"""Bench scenario "pymodbus baseline": the same polling with pymodbus's async serial client.

pymodbus is not a dependency of drivebus: it is imported only when this scenario runs
(``pip install 'drivebus[bench]'`` brings a tested version). Without it the scenario
gives one row whose note says so, and the other scenarios run as usual.
"""

from __future__ import annotations

import importlib.metadata
import importlib.util
import inspect
import logging
import time
from dataclasses import asdict

from drivebus.bench.common import (
    S115200,
    BenchOptions,
    BenchResult,
    Scenario,
    SimProcess,
    at_most,
    wire_figures,
)
from drivebus.settings import LineSettings

__all__ = ["SCENARIO", "pymodbus_baseline", "pymodbus_missing"]

MISSING_NOTE = (
    "pymodbus is not installed, so there is no baseline to compare with: "
    "pip install 'drivebus[bench]' (or any pymodbus 3.x) and run again"
)


def pymodbus_missing() -> str | None:
    """Why the baseline cannot run here (pymodbus not importable), or None if it can."""
    try:
        found = importlib.util.find_spec("pymodbus") is not None
    except (ImportError, ValueError):  # a broken or blocked installation
        found = False
    return None if found else MISSING_NOTE

S19200_8N2 = LineSettings.parse("19200 8N2")
"""19200 with a format a pty carries to the slaves' process."""


async def pymodbus_baseline(
    label: str, settings: LineSettings, n: int, seconds: float, turnaround: float, *,
    strict: bool,
) -> BenchResult:
    """``n`` slaves (in another process) polled in turn by pymodbus's
    ``AsyncModbusSerialClient``.

    ``strict``: the simulated slaves lose a frame sent without the t3.5 silence, as the
    spec's state machine does; otherwise they answer it anyway (many real slaves do) and
    the violation is only counted.
    """
    from pymodbus.client import AsyncModbusSerialClient
    from pymodbus.exceptions import ModbusIOException

    logging.getLogger("pymodbus").setLevel(logging.CRITICAL)  # it logs every lost reply
    kind = "strict" if strict else "lenient"
    async with SimProcess.slaves(n, [settings], turnaround, strict=strict) as sim:
        client = AsyncModbusSerialClient(
            port=sim.paths[0], baudrate=settings.baudrate, bytesize=settings.bytesize,
            parity=settings.parity, stopbits=settings.stopbits, timeout=0.1, retries=0,
        )
        await client.connect()
        failed = 0
        # The unit keyword is device_id from pymodbus 3.10 on, slave before.
        params = inspect.signature(client.read_holding_registers).parameters
        unit_kw = "device_id" if "device_id" in params else "slave"

        async def read(unit: int) -> None:
            nonlocal failed
            try:
                await client.read_holding_registers(0, count=2, **{unit_kw: unit})
            except ModbusIOException:
                failed += 1  # the slave lost the frame (e.g. sent without the silence)

        try:
            deadline = time.monotonic() + 0.2
            while time.monotonic() < deadline:
                await read(1)
            await sim.clear()
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
        fig = wire_figures(next(iter((await sim.logs()).values())), turnaround)
    row = asdict(fig)
    row["failed_requests"] = failed
    row["master_cpu_us_per_tx"] = cpu / max(fig.transactions, 1) * 1e6
    row["pymodbus"] = importlib.metadata.version("pymodbus")
    return BenchResult("pymodbus baseline", f"{label} x{n} {kind} slaves", row,
                       {"violations": at_most(0)})


async def run(opts: BenchOptions) -> list[BenchResult]:
    """8 slaves at 19200 and at 115200, strict and lenient slaves (one note row without
    pymodbus)."""
    missing = pymodbus_missing()
    if missing:
        return [BenchResult("pymodbus baseline", "not run", {"note": missing})]
    return [
        await pymodbus_baseline(label, s, 8, opts.seconds, opts.turnaround, strict=strict)
        for label, s in (("19200 8N2", S19200_8N2), ("115200 8N1", S115200))
        for strict in (True, False)
    ]


SCENARIO = Scenario("pymodbus baseline", 50, run)
