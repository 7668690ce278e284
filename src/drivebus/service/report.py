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

__all__ = ["report_data", "report_html", "report_png"]

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
#marks {{ display: flex; flex-wrap: wrap; gap: .9rem; font-size: .8rem; color: var(--dim);
  margin: .4rem 0; }}
#marks i {{ display: inline-block; width: 1.2rem; height: 0; border-top: 2px solid;
  vertical-align: middle; margin-right: .3rem; }}
#marks b {{ display: inline-block; width: .9rem; height: .6rem; vertical-align: middle;
  margin-right: .3rem; }}
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


def report_png(rec: Recording, path: str | Path, *, dpi: int = 110) -> None:
    """The report's charts as one static picture (matplotlib: ``pip install
    'drivebus[plots]'``): per axis position (and target) with velocity on a second scale,
    its events marked (planned arrivals dashed); per line utilisation and transactions/s."""
    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:
        from drivebus.errors import ConfigError

        raise ConfigError("--png needs matplotlib: pip install 'drivebus[plots]'") from None
    data = report_data(rec)
    n = len(data["axes"]) + len(data["lines"])
    fig, panels = plt.subplots(max(n, 1), 1, figsize=(11, 2.4 * max(n, 1) + 0.6),
                               sharex=True, squeeze=False)
    fig.suptitle(f"drivebus recording: {data['machine'] or 'machine'} "
                 f"({data['started_iso']}, {data['duration']:.2f} s)", fontsize=11)
    for ax, a in zip(panels[:, 0], data["axes"], strict=False):
        ax.plot(a["t"], a["position"], color="#0969da", lw=1.8, label=f"position ({a['unit']})")
        ax.plot(a["t"], [float("nan") if v is None else v for v in a["target"]],
                color="#bf8700", lw=1.2, ls="--", label="target")
        ax.set_ylabel(f"{a['name']} ({a['unit']})")
        if any(v is not None for v in a["velocity"]):
            v_ax = ax.twinx()
            v_ax.plot(a["t"], [float("nan") if v is None else v for v in a["velocity"]],
                      color="#2da44e", lw=1.0, label=f"velocity ({a['unit']}/s)")
            v_ax.set_ylabel(f"{a['unit']}/s", color="#2da44e")
        for m in a["marks"]:
            ax.axvline(m["t"], color=_MARK_COLORS.get(m["kind"], "#8b949e"),
                       ls="--" if m["kind"] in ("planned", "accepted") else "-",
                       lw=1.4 if m["kind"] in ("planned", "in_position") else 0.8)
        ax.grid(alpha=0.3)
        ax.legend(loc="upper left", fontsize=8)
    for ax, ln in zip(panels[len(data["axes"]):, 0], data["lines"], strict=False):
        ax.fill_between(ln["t"], ln["utilisation"], step="post", color="#0969da", alpha=0.3,
                        label="utilisation %")
        ax.set_ylim(0, 100)
        ax.set_ylabel(f"line {ln['name']} (%)")
        r_ax = ax.twinx()
        r_ax.step(ln["t"], ln["rate"], where="post", color="#2da44e", lw=1.0)
        r_ax.set_ylabel("transactions/s", color="#2da44e")
        ax.grid(alpha=0.3)
        ax.legend(loc="upper left", fontsize=8)
    panels[-1, 0].set_xlabel("seconds since the recording started "
                             "(dashed violet: planned arrival, solid blue: observed)")
    panels[-1, 0].set_xlim(0, max(data["duration"], 1e-3))
    fig.tight_layout()
    fig.savefig(str(path), dpi=dpi)
    plt.close(fig)
