"""A 30 s randomized soak with a fixed seed: concurrent moves, jogs, stops, emergency stops,
cancellations, group moves, out-of-limit requests, alarms and power cycles on eight axes of
four drive kinds, judged by the twins (see ``drivebus.sim.soak``)."""

from __future__ import annotations

from drivebus.sim.soak import run_soak


async def test_a_30_s_soak_keeps_every_invariant() -> None:
    report = await run_soak(30.0, seed=20261124)
    assert report.violations == []
    calls = report.calls
    for what in ("move_to", "move_by", "jog", "stop", "halt_now", "group move_to",
                 "move_to (cancelled)", "move_to (outside limits)"):
        assert calls[what] > 0, what
    assert report.faults["power cycle"] > 0 and report.faults["alarm"] > 0
    assert report.outcomes["move_to (cancelled): timed out"] > 0
    assert report.stops_checked > 50 and report.rest_checks > 1000
    assert report.outcomes["move_to (outside limits): LimitViolation"] > 0
    assert report.outcomes["move_to: ok"] > 0 and report.outcomes["stop: ok"] > 0
    # every call ended one way: returned, raised a typed error, timed out or was cancelled
    assert sum(report.outcomes.values()) == sum(calls.values())
