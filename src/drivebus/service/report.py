"""The recording report: one self-contained HTML file that charts a ``Recording``.

Per axis its position, velocity and target against time in the axis's own units, its
state as a band and its motion events as marks (a move's planned arrival dashed, the
observed one solid); per line its utilisation, transactions/s and reply latency; a table
of every move's planned and observed arrival. All charts share one time axis, so a group
move shows every axis on it. The chart library (uPlot, vendored in ``static/vendor``) and
the data are inlined: the file opens anywhere, with no network. The live dashboard draws
with the same ``static/charts.js``.

No FastAPI here: the CLI (``drivebus record``) and the bench use it without the service.
"""

from __future__ import annotations

import json
import math
from dataclasses import asdict
from html import escape
from pathlib import Path
from typing import Any

from drivebus.motion.recording import Recording

__all__ = ["held", "report_data", "report_figure", "report_html", "report_png", "state_runs"]

STATIC = Path(__file__).resolve().parent / "static"

LOAD_BIN = 0.1
"""Seconds per bin of the lines' utilisation and rates."""

_TEMPLATE = """<!doctype html>
<html lang="en">
<head>
<meta charset="utf-8">
<meta name="viewport" content="width=device-width, initial-scale=1">
<title>{title}</title>
<style>{uplot_css}</style>
<style>
:root {{ --bg: #101418; --panel: #1b2128; --line: #2c353f; --text: #e8edf2; --dim: #93a1ae;
  font-family: system-ui, -apple-system, "Segoe UI", Roboto, sans-serif; }}
body {{ margin: 0; background: var(--bg); color: var(--text); padding: 1rem 1.5rem; }}
h1 {{ margin: 0 0 .2rem; font-size: 1.4rem; }}
#meta, .hint {{ color: var(--dim); font-size: .9rem; }}
.chart {{ background: var(--panel); border: 1px solid var(--line); border-radius: .5rem;
  padding: .4rem; margin: .6rem 0; }}
.uplot {{ color: var(--text); }}
.u-title {{ font-size: 1rem; font-weight: 600; color: var(--text); }}
.u-legend {{ color: var(--dim); font-size: .8rem; }}
table {{ border-collapse: collapse; margin: .6rem 0; font-size: .9rem; }}
th, td {{ padding: .25rem .6rem; border-bottom: 1px solid var(--line); text-align: left; }}
th {{ color: var(--dim); font-weight: 500; }}
.chart-legend {{ display: flex; flex-wrap: wrap; gap: .9rem; font-size: .8rem;
  color: var(--dim); margin: .4rem 0; }}
.chart-legend i {{ display: inline-block; width: 1.2rem; height: 0; border-top: 2px solid;
  vertical-align: middle; margin-right: .3rem; }}
.chart-legend b {{ display: inline-block; width: .9rem; height: .6rem;
  vertical-align: middle; margin-right: .3rem; }}
</style>
</head>
<body>
<h1 id="title">{title}</h1>
<div id="meta"></div>
<table id="arrivals"><thead><tr><th>axis</th><th>move</th><th>started (s)</th>
<th>planned arrival (s)</th><th>observed arrival (s)</th><th>observed − planned</th>
</tr></thead><tbody></tbody></table>
<div id="marks"></div>
<div class="hint">Times in seconds since the recording started. Drag across a chart to
zoom in, double-click to zoom out; the cursor follows on every chart.</div>
<div id="charts"></div>
<script>{uplot_js}</script>
<script>{charts_js}</script>
<script>window.DRIVEBUS_REPORT = {data};</script>
<script>{report_js}</script>
</body>
</html>
"""


def _finite(v: float | None) -> float | None:
    return v if v is None or math.isfinite(v) else None


def report_data(rec: Recording, *, load_bin: float = LOAD_BIN) -> dict[str, Any]:
    """What the report plots, as JSON-ready data (times: seconds since the start)."""
    t0 = rec.started
    axes = []
    for trace in rec.axes.values():
        series = trace.series(t0)
        marks: list[dict[str, Any]] = []
        for e in trace.events:
            marks.append({"t": e.time - t0, "kind": e.kind, "what": e.what})
            if e.kind == "started" and e.planned_end is not None:
                marks.append({"t": e.planned_end - t0, "kind": "planned", "what": e.what})
        axes.append({
            "name": trace.name, "unit": trace.unit, "drive": trace.drive,
            "line": trace.line, "address": trace.address,
            **{k: [_finite(v) if isinstance(v, float) else v for v in vs]
               for k, vs in series.items()},
            "marks": marks,
        })
    lines = []
    for name in rec.lines:
        load = rec.line_load(name, load_bin)
        lines.append({
            "name": name,
            "t": load.t,
            "utilisation": [round(u * 100, 3) for u in load.utilisation],
            "rate": load.rate,
            "latency": [None if x is None else x * 1000 for x in load.latency],
        })
    header = rec.header()
    return {
        "machine": rec.machine_name,
        "started_iso": header["started_iso"],
        "duration": rec.duration,
        "dropped": sum(asdict(rec.dropped).values()),
        "axes": axes,
        "lines": lines,
        "arrivals": [asdict(a) for a in rec.arrivals()],
    }


def _asset(name: str) -> str:
    return (STATIC / name).read_text(encoding="utf-8")


def _script(text: str) -> str:
    """Text safe inside a <script> element."""
    return text.replace("</script", "<\\/script")


def report_html(rec: Recording, *, title: str | None = None) -> str:
    """The recording as one self-contained HTML page."""
    data = json.dumps(report_data(rec), separators=(",", ":")).replace("</", "<\\/")
    return _TEMPLATE.format(
        title=escape(title or f"drivebus recording: {rec.machine_name or 'machine'}"),
        uplot_css=_asset("vendor/uplot/uPlot.min.css"),
        uplot_js=_script(_asset("vendor/uplot/uPlot.iife.min.js")),
        charts_js=_script(_asset("charts.js")),
        report_js=_script(_asset("report.js")),
        data=data,
    )


_MARK_COLORS = {"accepted": "#8b949e", "started": "#2da44e", "stop": "#bf8700",
                "in_position": "#0969da", "done": "#0969da", "aborted": "#bf8700",
                "error": "#cf222e", "planned": "#8250df"}
_MARK_LABELS = {"accepted": "accepted", "started": "start", "stop": "stop",
                "in_position": "arrived", "done": "done", "aborted": "aborted",
                "error": "error", "planned": "planned arrival"}
"""As the HTML report's marks (static/charts.js), on a white background."""
_STATE_COLORS = {"Standstill": "#8fd19e", "DiscreteMotion": "#54aeff",
                 "ContinuousMotion": "#80ccff", "Homing": "#c297ff", "Stopping": "#d4a72c",
                 "ErrorStop": "#ff8182", "Offline": "#cf222e", "Disabled": "#afb8c1"}


def held(t: list[float], values: list[float | None]) -> tuple[list[float], list[float]]:
    """The polyline that draws ``values`` sampled at ``t`` as steps: each sample held until
    the next (what is known between two polls is the earlier one); a missing value (None)
    breaks the line (NaN)."""
    xs: list[float] = []
    ys: list[float] = []
    for i, (when, v) in enumerate(zip(t, values, strict=True)):
        y = float("nan") if v is None else float(v)
        if i:
            xs.append(when)
            ys.append(ys[-1])  # the one before, held up to this sample
        xs.append(when)
        ys.append(y)
    return xs, ys


def state_runs(t: list[float], states: list[str], end: float) -> list[tuple[float, float, str]]:
    """Runs of equal states ``(start, end, state)``, the last one up to ``end``."""
    runs: list[tuple[float, float, str]] = []
    for when, st in zip(t, states, strict=True):
        if runs and runs[-1][2] == st:
            continue
        if runs:
            runs[-1] = (runs[-1][0], when, runs[-1][2])
        runs.append((when, when, st))
    if runs:
        runs[-1] = (runs[-1][0], max(end, runs[-1][0]), runs[-1][2])
    return runs


def report_figure(rec: Recording) -> Any:
    """The report's charts as a matplotlib figure (``report_png`` saves it): per axis its
    position and target (held from poll to poll) with velocity on a second scale, its
    state as a band and its events marked; per line utilisation and transactions/s; one
    legend for the series of each panel, one for the marks and states."""
    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
        from matplotlib.lines import Line2D
        from matplotlib.patches import Patch
    except ImportError:
        from drivebus.errors import ConfigError

        raise ConfigError("--png needs matplotlib: pip install 'drivebus[plots]'") from None
    data = report_data(rec)
    n = len(data["axes"]) + len(data["lines"])
    fig, panels = plt.subplots(max(n, 1), 1, figsize=(11, 2.4 * max(n, 1) + 1.2),
                               sharex=True, squeeze=False)
    fig.suptitle(f"drivebus recording: {data['machine'] or 'machine'} "
                 f"({data['started_iso']}, {data['duration']:.2f} s)", fontsize=11)
    kinds: set[str] = set()
    states: set[str] = set()
    for ax, a in zip(panels[:, 0], data["axes"], strict=False):
        ax.plot(*held(a["t"], a["position"]), color="#0969da", lw=1.8,
                label=f"position ({a['unit']})")
        ax.plot(*held(a["t"], a["target"]), color="#bf8700", lw=1.2, ls="--",
                label=f"target ({a['unit']})")
        ax.set_ylabel(f"{a['name']} ({a['unit']})")
        handles, labels = ax.get_legend_handles_labels()
        if any(v is not None for v in a["velocity"]):
            v_ax = ax.twinx()
            v_ax.plot(*held(a["t"], a["velocity"]), color="#2da44e", lw=1.0,
                      label=f"velocity ({a['unit']}/s)")
            v_ax.set_ylabel(f"{a['unit']}/s", color="#2da44e")
            more, more_labels = v_ax.get_legend_handles_labels()
            handles, labels = handles + more, labels + more_labels
        for t0, t1, st in state_runs(a["t"], a["state"], data["duration"]):
            ax.broken_barh([(t0, t1 - t0)], (0, 0.05), transform=ax.get_xaxis_transform(),
                           facecolors=_STATE_COLORS.get(st, "#d0d7de"), zorder=0)
            states.add(st)
        for m in a["marks"]:
            ax.axvline(m["t"], color=_MARK_COLORS.get(m["kind"], "#8b949e"),
                       ls="--" if m["kind"] in ("planned", "accepted") else "-",
                       lw=1.4 if m["kind"] in ("planned", "in_position") else 0.8)
            kinds.add(m["kind"])
        ax.grid(alpha=0.3)
        ax.legend(handles, labels, loc="upper left", fontsize=8)
    for ax, ln in zip(panels[len(data["axes"]):, 0], data["lines"], strict=False):
        ax.fill_between(ln["t"], ln["utilisation"], step="post", color="#0969da", alpha=0.3,
                        label="utilisation %")
        ax.set_ylim(0, 100)
        ax.set_ylabel(f"line {ln['name']} (%)")
        r_ax = ax.twinx()
        r_ax.step(ln["t"], ln["rate"], where="post", color="#2da44e", lw=1.0,
                  label="transactions/s")
        r_ax.set_ylabel("transactions/s", color="#2da44e")
        ax.grid(alpha=0.3)
        handles, labels = ax.get_legend_handles_labels()
        more, more_labels = r_ax.get_legend_handles_labels()
        ax.legend(handles + more, labels + more_labels, loc="upper left", fontsize=8)
    keys: list[Any] = [
        Line2D([], [], color=_MARK_COLORS[k], lw=1.4 if k in ("planned", "in_position") else 0.8,
               ls="--" if k in ("planned", "accepted") else "-", label=_MARK_LABELS[k])
        for k in _MARK_LABELS if k in kinds
    ] + [Patch(facecolor=_STATE_COLORS.get(st, "#d0d7de"), label=f"state: {st}")
         for st in _STATE_COLORS if st in states]
    if keys:
        fig.legend(handles=keys, loc="lower center", ncol=min(len(keys), 6), fontsize=8,
                   frameon=False)
    panels[-1, 0].set_xlabel("seconds since the recording started")
    panels[-1, 0].set_xlim(0, max(data["duration"], 1e-3))
    fig.tight_layout(rect=(0, 0.05 if keys else 0, 1, 1))
    return fig


def report_png(rec: Recording, path: str | Path, *, dpi: int = 110) -> None:
    """The report's charts as one static picture (matplotlib: ``pip install
    'drivebus[plots]'``), as ``report_figure`` draws them."""
    fig = report_figure(rec)  # a ConfigError without matplotlib
    import matplotlib.pyplot as plt

    try:
        fig.savefig(str(path), dpi=dpi)
    finally:
        plt.close(fig)
