"""The benchmark runs end to end (tiny counts), so it never rots; figures are not asserted."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

from drivebus.bench import format_table, results_json, run_bench, scenarios
from drivebus.errors import ArgumentError

BUILT_IN = {
    "efficiency", "stop latency", "cpu", "scale", "pymodbus baseline", "pipelined tcp", "flood",
    "service",
}


MOTION = "motion"
"""The motion scenario (a minute of real-time moves on the twins, judged by the twins and
asserting no figure) runs beside other tests; the rest of the bench runs alone."""


@pytest.mark.serial  # it measures
async def test_quick_bench_runs_every_scenario_without_gap_violations() -> None:
    found = [s.name for s in scenarios()]
    assert set(found) >= BUILT_IN | {MOTION}
    results = await run_bench(quick=True, seconds=0.15, only=set(found) - {MOTION})
    # every other scenario module found gave rows, in the declared order
    assert list(dict.fromkeys(r.scenario for r in results)) == [n for n in found if n != MOTION]
    for r in results:
        if r.scenario in ("efficiency", "scale"):
            assert r.figures["violations"] == 0, r
        if r.scenario == "efficiency":  # measured on the wire of the slaves' own process
            assert 0 < r.figures["efficiency"] <= 1.0, r
            assert 0 < r.figures["efficiency_in_process"] <= 1.0, r
            # the bare master beside it, on the same slaves: a floor, not a target
            assert 0 < r.figures["floor_efficiency"] <= 1.0, r
            assert 0 < r.figures["floor_thread_efficiency"] <= 1.0, r
            assert r.figures["floor_violations"] == 0, r
        if r.scenario == "scale":
            assert r.figures["transactions"] > 0 and r.figures["moves"] > 0, r
            assert r.figures["busy_cores"] > r.figures["sim_cpu_cores"] > 0, r
        assert set(r.targets) <= set(r.figures), r  # every target sits beside its figure
    tcp = {r.case.split(",")[1].strip(): r.figures for r in results
           if r.scenario == "pipelined tcp"}
    assert set(tcp) == {"1 in flight", "8 in flight", "16 callers"}
    assert all(f["tps"] > 0 for f in tcp.values())
    cpu = next(r for r in results if r.scenario == "cpu")
    assert cpu.figures["ratio"] > 0 and "ratio" in cpu.targets
    flood = {r.case.split(",")[0]: r.figures for r in results if r.scenario == "flood"}
    assert set(flood) == {"none", "line rate", "flat out"}
    for figures in flood.values():
        assert figures["healthy_violations"] == 0 and figures["healthy_transactions"] > 0
    assert flood["none"]["line_noise"] == 0
    assert isinstance(flood["flat out"]["line_noise"], int) and flood["flat out"]["line_noise"] > 0
    alone, *watched = (r.figures for r in results if r.scenario == "service")
    assert len(watched) == 2  # as polled, and at the dashboard's max_rate
    assert alone["violations"] == 0 and 0 < alone["efficiency"] <= 1.0
    for row in watched:
        assert row["violations"] == 0 and 0 < row["efficiency"] <= 1.0
        assert row["updates"] > 0 and row["jog_feeds"] > 0  # 50 watched, one commanded
        assert {"drop_points", "update_p50_ms", "update_p99_ms"} <= set(row)
    stop = next(r for r in results if r.scenario == "stop latency")
    assert stop.figures["stops"] == 20
    table = format_table(results)
    assert "efficiency" in table and "target" in table and "≥ 0.97" in table
    rows = json.loads(results_json(results))
    assert len(rows) == len(results)
    eff = next(r for r in rows if r["scenario"] == "efficiency")
    assert eff["targets"]["efficiency"] == {"op": ">=", "value": 0.97}
    assert isinstance(eff["missed"], list)


async def test_quick_bench_motion_keeps_the_axis_guarantees(tmp_path: Path) -> None:
    results = await run_bench(quick=True, seconds=0.15, only={MOTION}, plots=tmp_path / "plots")
    # the motion scenario drew its group moves: a self-contained report and a picture
    html = (tmp_path / "plots" / "motion-group-moves.html").read_text()
    assert "uPlot" in html and "http://" not in html.replace("http://www.w3.org", "")
    for axis in ("\"x\"", "\"y\"", "\"z\"", "\"r\""):
        assert axis in html
    assert (tmp_path / "plots" / "motion-group-moves.png").stat().st_size > 10_000
    assert results and {r.scenario for r in results} == {MOTION}
    for r in results:
        assert set(r.targets) <= set(r.figures), r  # every target sits beside its figure
    motion = {r.case: r.figures for r in results}
    for kind in ("x (NT86)", "y (BHSS)", "z (CL86R)", "r (EPR60)"):
        assert motion[f"stop to rest {kind}"]["stops"] == 4
        jog = motion[f"jog overshoot {kind}"]
        assert jog["overshoot_steady"] == 0 and jog["overshoot_speed_change"] == 0
    for kind in ("x (NT86)", "y (BHSS)", "z (CL86R)", "r (EPR60)"):
        dwell = motion[f"buffered dwell {kind}"]
        assert dwell["moves"] == 6 and dwell["dwell_max_ms"] > 0
    # Every move after the first was blended, at a speed above zero. Whether each blend
    # reached the drive before it stopped depends on this process's load (the twins run in
    # it): the serial test_a_blended_sequence_never_reaches_zero_speed_between_its_moves
    # judges that on the twins; here the figure is reported.
    blend = motion["blend z (CL86R)"]
    assert blend["blended"] == blend["moves"] - 1 and blend["planned_blend_speed_min"] > 0
    assert blend["min_speed_between_mm_s"] >= 0
    paths = {case: f for case, f in motion.items() if case.startswith("path")}
    assert len(paths) == 2 and all(f["deviation_twins_mm"] >= 0 for f in paths.values())
    soak = next(f for case, f in motion.items() if case.startswith("soak"))
    assert soak["violations"] == 0 and soak["calls"] > 0  # (the log names each violation)
    assert (soak["ok"] + soak["typed_errors"] + soak["timed_out"] + soak["cancelled"]
            == soak["calls"])


async def test_scenarios_can_be_chosen_by_name() -> None:
    results = await run_bench(quick=True, seconds=0.1, only={"cpu"})
    assert [r.scenario for r in results] == ["cpu"]
    with pytest.raises(ArgumentError, match="no bench scenario named nope"):
        await run_bench(quick=True, only={"nope"})


async def test_pymodbus_baseline_polls_with_the_installed_pymodbus() -> None:
    results = await run_bench(quick=True, seconds=0.15, only={"pymodbus baseline"})
    assert len(results) == 4
    for r in results:
        assert r.figures["transactions"] > 0, r
        assert isinstance(r.figures["pymodbus"], str) and r.figures["pymodbus"].startswith("3.")


def test_bench_without_pymodbus_says_so_and_runs_the_rest() -> None:
    code = (
        "import sys; sys.modules['pymodbus'] = None  # as if it were not installed\n"
        "import anyio\n"
        "from drivebus.bench import format_table, run_bench\n"
        "rows = anyio.run(lambda: run_bench(quick=True, seconds=0.1,"
        " only={'pymodbus baseline', 'cpu'}))\n"
        "print(format_table(rows))\n"
    )
    out = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, timeout=120, check=True
    ).stdout
    assert "== cpu" in out
    assert "== pymodbus baseline" in out
    assert "note=pymodbus is not installed" in out and "drivebus[bench]" in out


def test_the_scale_rows_simulators_take_the_cores_the_master_and_its_workers_leave() -> None:
    from drivebus.bench.scale import sim_processes

    assert sim_processes(16, 1, cores=2) == 2  # a small machine: the drives share its cores
    assert sim_processes(16, 0, cores=16) == 15
    assert sim_processes(16, 4, cores=16) == 11  # ~1.5 lines each: a late reply is not theirs
    assert sim_processes(4, 0, cores=64) == 4  # at most one per line
    assert sim_processes(1, 0, cores=2) == 1  # never a simulator with no line
