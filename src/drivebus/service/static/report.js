// The drivebus recording report: builds its charts from the recording embedded in the page
// (DRIVEBUS_REPORT). Every chart shares one time axis (seconds since the recording started)
// and one cursor; drag to zoom in, double-click to zoom out.
"use strict";

(() => {
  const R = window.DRIVEBUS_REPORT;
  const $ = (id) => document.getElementById(id);
  const fmt = (v, d = 3) => (v === null || v === undefined ? "–" : Number(v).toFixed(d));

  $("title").textContent = `drivebus recording: ${R.machine || "machine"}`;
  $("meta").textContent = `started ${R.started_iso} · ${fmt(R.duration, 2)} s · ` +
    `${R.axes.length} axes · ${R.lines.length} lines` +
    (R.dropped ? ` · dropped (ring full): ${R.dropped}` : "");

  // planned and observed arrivals
  const body = $("arrivals").tBodies[0];
  for (const a of R.arrivals) {
    const tr = document.createElement("tr");
    const late = a.planned !== null && a.observed !== null
      ? `${fmt((a.observed - a.planned) * 1000, 1)} ms` : a.outcome;
    for (const v of [a.axis, a.what, fmt(a.started), fmt(a.planned), fmt(a.observed), late]) {
      const td = document.createElement("td");
      td.textContent = v;
      tr.append(td);
    }
    body.append(tr);
  }
  $("arrivals").hidden = !R.arrivals.length;

  DrivebusCharts.legend($("marks"));

  const xRange = [0, Math.max(R.duration, 1e-3)];
  const charts = $("charts");
  for (const a of R.axes) {
    const div = document.createElement("div");
    div.className = "chart";
    charts.append(div);
    const chart = DrivebusCharts.axisChart(div, {
      name: a.name, unit: a.unit, data: [a.t, a.position, a.velocity, a.target],
      extra: { states: DrivebusCharts.stateRuns(a.t, a.state, R.duration), marks: a.marks },
    });
    chart.u.setScale("x", { min: xRange[0], max: xRange[1] });
  }
  for (const ln of R.lines) {
    const div = document.createElement("div");
    div.className = "chart";
    charts.append(div);
    const chart = DrivebusCharts.lineChart(div, {
      name: ln.name, data: [ln.t, ln.utilisation, ln.rate, ln.latency],
    });
    chart.u.setScale("x", { min: xRange[0], max: xRange[1] });
  }
  window.addEventListener("resize", () => DrivebusCharts.fit());
  document.body.dataset.ready = "true";
})();
