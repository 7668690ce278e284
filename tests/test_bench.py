"""The benchmark runs end to end (tiny counts), so it never rots; figures are not asserted."""

from __future__ import annotations

import json

from drivebus.bench import format_table, results_json, run_bench


async def test_quick_bench_runs_every_scenario_without_gap_violations() -> None:
    results = await run_bench(quick=True, seconds=0.15)
    scenarios = {r.scenario for r in results}
    assert scenarios == {"efficiency", "stop latency", "cpu", "scale", "pymodbus baseline"}
    for r in results:
        if r.scenario in ("efficiency", "scale"):
            assert r.figures["violations"] == 0, r
        if r.scenario == "efficiency":
            assert r.figures["transactions"] > 0 and 0 < r.figures["efficiency"] <= 1.0, r
    stop = next(r for r in results if r.scenario == "stop latency")
    assert stop.figures["stops"] == 20
    assert "efficiency" in format_table(results)
    assert len(json.loads(results_json(results))) == len(results)
