"""drivebus bench: bus efficiency against the wire limit, stop latency, CPU, scale, baseline.

Every scenario runs on simulated lines (wire time emulated, slave turnaround default 1 ms)
and is measured from the simulator's wire log, not from the master's own bookkeeping.

One module per scenario. A module of this package that defines ``SCENARIO`` (a
``Scenario``: its name, its place in the run, and ``async def run(BenchOptions) ->
list[BenchResult]``) is found and run by ``run_bench`` and ``drivebus bench``; adding a
scenario is adding such a module, nothing else changes. ``common`` holds what
scenarios share: options, result rows, wire-log figures, pollers, tables and JSON.
"""

from __future__ import annotations

import importlib
import pkgutil
from collections.abc import Collection
from pathlib import Path

from drivebus.bench.common import (
    BenchOptions,
    BenchResult,
    LoopSteps,
    Scenario,
    WireFigures,
    format_table,
    results_json,
    wire_figures,
)
from drivebus.bench.cpu import cpu_per_transaction
from drivebus.bench.efficiency import efficiency
from drivebus.bench.pymodbus_baseline import pymodbus_baseline
from drivebus.bench.scale import scale
from drivebus.bench.stop_latency import stop_latency
from drivebus.errors import ArgumentError

__all__ = [
    "BenchOptions",
    "BenchResult",
    "Scenario",
    "WireFigures",
    "cpu_per_transaction",
    "efficiency",
    "format_table",
    "pymodbus_baseline",
    "results_json",
    "run_bench",
    "scale",
    "scenarios",
    "stop_latency",
    "wire_figures",
]


def scenarios() -> list[Scenario]:
    """Every scenario module's ``SCENARIO`` in this package, in run order."""
    found: list[Scenario] = []
    for info in pkgutil.iter_modules(__path__):
        module = importlib.import_module(f"{__name__}.{info.name}")
        scenario = getattr(module, "SCENARIO", None)
        if isinstance(scenario, Scenario):
            found.append(scenario)
    return sorted(found, key=lambda s: (s.order, s.name))


async def run_bench(
    *,
    quick: bool = False,
    turnaround: float = 0.001,
    seconds: float | None = None,
    only: Collection[str] | None = None,
    plots: Path | None = None,
) -> list[BenchResult]:
    """Run every scenario (or those named in ``only``); ``quick`` shortens them, ``seconds``
    sets each timed run's length; ``plots`` is where the motion scenario draws its moves."""
    opts = BenchOptions(
        quick=quick, seconds=seconds or (0.6 if quick else 3.0), turnaround=turnaround,
        plots=plots,
    )
    chosen = scenarios()
    if only is not None:
        unknown = set(only) - {s.name for s in chosen}
        if unknown:
            raise ArgumentError(
                f"only={sorted(only)!r}: no bench scenario named {', '.join(sorted(unknown))}; "
                f"there are {', '.join(s.name for s in chosen)}"
            )
        chosen = [s for s in chosen if s.name in only]
    results: list[BenchResult] = []
    for scenario in chosen:
        with LoopSteps() as steps:
            rows = await scenario.run(opts)
        for row in rows:  # how long this process held its event loop at most
            row.figures["longest_loop_step_ms"] = round(steps.longest * 1e3, 2)
            row.figures["longest_gc_pass_ms"] = round(steps.longest_gc * 1e3, 2)
        results.extend(rows)
    return results
