// drivebus charts: one axis's position, velocity and target against time (its own units),
// its state as a band, its motion events as marks; one line's utilisation, transactions/s
// and reply latency. Built on uPlot (vendor/uplot, MIT). Shared by the live dashboard and
// the self-contained HTML report (`drivebus record`), so both draw the same pictures.
//
// An axis's samples are polls: what is known between two of them is the earlier one, so
// they are drawn as steps that hold each sample until the next (a straight line between
// two polls a second apart drew a drift and a ramp that never happened), and a missing
// value (null) breaks the line.
"use strict";

const DrivebusCharts = (() => {
  const THEME = {
    text: "#93a1ae", grid: "#2c353f", position: "#58a6ff", velocity: "#3fb950",
    target: "#e3b341", utilisation: "#58a6ff", rate: "#3fb950", latency: "#f778ba",
  };
  const STATE_COLORS = {
    Standstill: "#23432c", DiscreteMotion: "#2f6fb3", ContinuousMotion: "#3d8bd9",
    Homing: "#7a5cc7", Stopping: "#b8860b", ErrorStop: "#f85149", Offline: "#f85149",
    Disabled: "#3a3f45",
  };
  const MARKS = {
    accepted: { color: "#93a1ae", label: "accepted", dash: [2, 3] },
    started: { color: "#3fb950", label: "start" },
    stop: { color: "#d29922", label: "stop" },
    in_position: { color: "#58a6ff", label: "arrived" },
    done: { color: "#58a6ff", label: "done" },
    aborted: { color: "#d29922", label: "aborted" },
    error: { color: "#f85149", label: "error" },
    planned: { color: "#bc8cff", label: "planned arrival", dash: [6, 4] },
  };
  const registry = new Map();   // chart id -> the chart (the tests read the plotted data)

  const held = () => uPlot.paths.stepped({ align: 1 });  // each sample until the next

  function axisStyle(label, side) {
    return {
      label, side, stroke: THEME.text, labelSize: 18, size: 56,
      grid: { stroke: THEME.grid, width: 1, show: side !== 1 },
      ticks: { stroke: THEME.grid, width: 1 },
    };
  }

  // Marks and the state band drawn over the plot (canvas pixels).
  function overlay(u, extra) {
    const ctx = u.ctx;
    const { left, top, width, height } = u.bbox;
    const px = devicePixelRatio || 1;
    ctx.save();
    ctx.beginPath();
    ctx.rect(left, top, width, height);
    ctx.clip();
    const x = (t) => u.valToPos(t, "x", true);
    for (const [t0, t1, state] of extra.states || []) {
      ctx.fillStyle = STATE_COLORS[state] || THEME.grid;
      const a = x(t0), b = x(t1);
      ctx.fillRect(a, top + height - 7 * px, Math.max(px, b - a), 7 * px);
    }
    ctx.font = `${10 * px}px system-ui, sans-serif`;
    ctx.textBaseline = "top";
    let row = 0;
    for (const m of extra.marks || []) {
      const style = MARKS[m.kind] || MARKS.accepted;
      const xp = x(m.t);
      if (xp < left - 1 || xp > left + width + 1) continue;
      ctx.strokeStyle = style.color;
      ctx.lineWidth = (m.kind === "planned" || m.kind === "in_position" ? 2 : 1) * px;
      ctx.setLineDash((style.dash || []).map((d) => d * px));
      ctx.beginPath();
      ctx.moveTo(xp, top);
      ctx.lineTo(xp, top + height - 8 * px);
      ctx.stroke();
      if (m.label !== "") {
        ctx.fillStyle = style.color;
        ctx.fillText(m.label ?? style.label, xp + 3 * px, top + (2 + 11 * (row % 3)) * px);
        row += 1;
      }
    }
    ctx.restore();
  }

  // onZoom(chart): called when the user drags across the chart to zoom in.
  function make(el, id, opts, data, extra, onZoom) {
    const chart = { id, extra };
    opts.hooks = { draw: [(u) => overlay(u, chart.extra)] };
    if (onZoom) opts.hooks.setSelect = [(u) => { if (u.select.width > 0) onZoom(chart); }];
    opts.width = opts.width || Math.max(300, (el.clientWidth || 808) - 8);
    chart.u = new uPlot(opts, data, el);
    chart.set = (d, ex, keepX) => {
      chart.extra = ex || chart.extra;
      chart.u.setData(d, !keepX);
    };
    chart.data = () => chart.u.data;
    registry.set(id, chart);
    return chart;
  }

  // One axis: data = [t, position, velocity, target]; extra = {states, marks}.
  function axisChart(el, { id, name, unit, height = 230, time = false, sync = "drivebus",
                           data = [[], [], [], []], extra = {}, onZoom }) {
    const opts = {
      title: `${name} (${unit})`, height,
      cursor: { sync: { key: sync }, drag: { x: true, y: false } },
      scales: { x: { time }, pos: { auto: true }, vel: { auto: true } },
      legend: { live: true },
      axes: [
        { ...axisStyle("", 2), size: 40 },
        { ...axisStyle(`position (${unit})`, 3), scale: "pos" },
        { ...axisStyle(`velocity (${unit}/s)`, 1), scale: "vel" },
      ],
      series: [
        { label: time ? "time" : "t (s)", value: (u, v) => (v == null ? "–" : time
          ? new Date(v * 1000).toLocaleTimeString() : v.toFixed(3)) },
        { label: `position ${unit}`, scale: "pos", stroke: THEME.position, width: 2,
          paths: held(), value: (u, v) => (v == null ? "–" : v.toFixed(3)) },
        { label: `velocity ${unit}/s`, scale: "vel", stroke: THEME.velocity, width: 1.5,
          paths: held(), value: (u, v) => (v == null ? "–" : v.toFixed(2)) },
        { label: `target ${unit}`, scale: "pos", stroke: THEME.target, width: 1.5,
          dash: [8, 5], paths: held(), value: (u, v) => (v == null ? "–" : v.toFixed(3)) },
      ],
    };
    return make(el, id || `axis-${name}`, opts, data, extra, onZoom);
  }

  // One line: data = [t, utilisation %, transactions/s, latency ms].
  function lineChart(el, { id, name, height = 200, time = false, sync = "drivebus",
                           data = [[], [], [], []], extra = {}, onZoom }) {
    const opts = {
      title: `line ${name}`, height,
      cursor: { sync: { key: sync }, drag: { x: true, y: false } },
      scales: { x: { time }, pct: { range: [0, 100] }, rate: { auto: true },
                ms: { auto: true } },
      axes: [
        { ...axisStyle("", 2), size: 40 },
        { ...axisStyle("utilisation (%)", 3), scale: "pct" },
        { ...axisStyle("transactions/s", 1), scale: "rate" },
        { ...axisStyle("reply latency (ms)", 1), scale: "ms" },
      ],
      series: [
        { label: time ? "time" : "t (s)", value: (u, v) => (v == null ? "–" : time
          ? new Date(v * 1000).toLocaleTimeString() : v.toFixed(3)) },
        { label: "utilisation %", scale: "pct", stroke: THEME.utilisation, width: 2,
          fill: "rgba(88,166,255,0.15)", value: (u, v) => (v == null ? "–" : v.toFixed(1)) },
        { label: "transactions/s", scale: "rate", stroke: THEME.rate, width: 1.5,
          value: (u, v) => (v == null ? "–" : v.toFixed(0)) },
        { label: "latency ms", scale: "ms", stroke: THEME.latency, width: 1.5,
          value: (u, v) => (v == null ? "–" : v.toFixed(2)) },
      ],
    };
    return make(el, id || `line-${name}`, opts, data, extra, onZoom);
  }

  // Runs of equal states: [[t0, t1, state], ...] from parallel arrays.
  function stateRuns(t, states, end) {
    const runs = [];
    for (let i = 0; i < t.length; i++) {
      const last = runs[runs.length - 1];
      if (last && last[2] === states[i]) last[1] = t[i];
      else {
        if (last) last[1] = t[i];
        runs.push([t[i], t[i], states[i]]);
      }
    }
    if (runs.length && end !== undefined) runs[runs.length - 1][1] = end;
    return runs;
  }

  // The legend of the marks and of the state band (the series have uPlot's own legend).
  function legend(el) {
    el.classList.add("chart-legend");
    for (const [kind, style] of Object.entries(MARKS)) {
      const span = document.createElement("span");
      span.innerHTML = `<i style="border-color:${style.color};` +
        `border-style:${style.dash ? "dashed" : "solid"}"></i>`;
      span.append(style.label);
      span.dataset.kind = kind;
      el.append(span);
    }
    const band = document.createElement("span");
    band.className = "band-title";
    band.textContent = "state (band at the bottom):";
    el.append(band);
    for (const [state, color] of Object.entries(STATE_COLORS)) {
      const span = document.createElement("span");
      span.innerHTML = `<b style="background:${color}"></b>`;
      span.append(state);
      span.dataset.state = state;
      el.append(span);
    }
    return el;
  }

  function fit(container) {
    for (const chart of registry.values()) {
      const el = chart.u.root.parentElement;
      if (!container || container.contains(el)) {
        const width = Math.max(300, el.clientWidth - 8);
        if (width !== chart.u.width) chart.u.setSize({ width, height: chart.u.height });
      }
    }
  }

  return { axisChart, lineChart, stateRuns, legend, fit, registry, MARKS, STATE_COLORS };
})();

window.DrivebusCharts = DrivebusCharts;
