"""The recording's static picture (``drivebus record --png``): what matplotlib draws is each
recorded poll held until the next (no straight line between two polls, which drew motion
that did not happen), the velocity is in the legend, and the marks and the state band
have a legend of their own."""

from __future__ import annotations

import math
from pathlib import Path

import anyio
import pytest

from drivebus.service.report import report_figure, report_png
from test_recording import recorded_group_move

plt = pytest.importorskip("matplotlib.pyplot", reason="matplotlib is not installed")


def test_the_png_holds_each_poll_and_has_legends_for_velocity_marks_and_states(
    tmp_path: Path,
) -> None:
    rec = anyio.run(recorded_group_move, "rec-png")  # drawn after, with no loop to hold
    fig = report_figure(rec)
    try:
        for name, trace in rec.axes.items():
            unit = trace.unit
            (panel,) = [a for a in fig.axes if a.get_ylabel() == f"{name} ({unit})"]
            lines = {ln.get_label(): ln for ln in panel.get_lines()}
            xs, ys = (list(map(float, v)) for v in lines[f"position ({unit})"].get_data())
            samples = list(trace.samples)
            t = [s.time - rec.started for s in samples]
            assert len(xs) == 2 * len(samples) - 1
            for k, s in enumerate(samples):  # every poll, and the one before held up to it
                assert (xs[2 * k], ys[2 * k]) == (t[k], s.position), (name, k)
                if k:
                    assert (xs[2 * k - 1], ys[2 * k - 1]) == (t[k], samples[k - 1].position)
            for i in range(len(xs) - 1):  # only flat stretches and jumps, no slopes
                assert xs[i] == xs[i + 1] or ys[i] == ys[i + 1] or math.isnan(ys[i]), (name, i)
            legend = [tx.get_text() for tx in panel.get_legend().get_texts()]
            assert legend == [f"position ({unit})", f"target ({unit})", f"velocity ({unit}/s)"]
            runs = [c for c in panel.collections if c.get_zorder() == 0]
            assert len(runs) >= 3  # standing, moving, standing again
        keys = [tx.get_text() for lg in fig.legends for tx in lg.get_texts()]
        for key in ("accepted", "start", "arrived", "planned arrival", "state: Standstill",
                    "state: DiscreteMotion"):
            assert key in keys, keys
    finally:
        plt.close(fig)
    png = tmp_path / "run.png"
    report_png(rec, png)
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and png.stat().st_size > 20_000
