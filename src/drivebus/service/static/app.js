// drivebus dashboard: live axes over WS /api/ws, commands over the public HTTP routes.
// Jog buttons are hold-to-run: pointer down starts a jog with a short TTL and feeds it
// over the WebSocket while held; release, leaving the button or losing the connection
// stops feeding (and sends speed 0), so the service's watchdog stops the axis anyway.
// Charts (charts.js on uPlot, served from the package): per axis position, velocity and
// target in its own units with its state as a band, per line transactions/s,
// utilisation and reply latency; times are the service's poll times on the wall clock.
// Before anything else the page asks the service who it is (GET /api/client): with
// tokens and none given it asks for one at once, and the E-STOP says that it is disabled
// and why until a token lets it act.
"use strict";

const JOG_TTL = 0.5;        // s: the axis stops this long after the last feed
const JOG_FEED = 150;       // ms between feeds while a jog button is held
const KEEP = 600;           // s of history kept (the widest window)
const DRAW_EVERY = 250;     // ms between chart redraws
const MAX_RATE = 20;        // axis/line updates per second: plenty for eyes and the plot

const state = {
  token: sessionStorage.getItem("drivebus-token") || "",
  ws: null,
  live: false,
  axes: new Map(),      // name -> last axis message
  series: new Map(),    // axis name -> {t, position, velocity, target, state, marks}
  lineSeries: new Map(),  // line name -> {t, utilisation, rate, latency, last}
  clockOffset: null,    // wall - monotonic of the service (from hello)
  window: 30,           // s shown
  paused: false,
  recording: null,      // id of the recording this page started
  jogs: new Map(),      // name -> release() of its held jog button
  scope: "command",
  authorized: false,    // the service took our token (or needs none): the E-STOP can act
  tokens: false,        // the service has tokens: the WebSocket sends ours first
};

const $ = (id) => document.getElementById(id);

function toast(text) {
  const t = $("toast");
  t.textContent = text;
  t.hidden = false;
  clearTimeout(toast.timer);
  toast.timer = setTimeout(() => { t.hidden = true; }, 5000);
}

function hideToast() {
  clearTimeout(toast.timer);
  $("toast").hidden = true;
}

function note(text, cls) {
  const li = document.createElement("li");
  li.textContent = `${new Date().toLocaleTimeString()} ${text}`;
  if (cls) li.className = cls;
  const list = $("events");
  list.prepend(li);
  while (list.children.length > 30) list.lastChild.remove();
}

// -- HTTP ----------------------------------------------------------------------------------

async function api(method, path, body) {
  const headers = { "X-Drivebus-Client": "dashboard" };
  if (state.token) headers.Authorization = `Bearer ${state.token}`;
  if (body !== undefined) headers["Content-Type"] = "application/json";
  const r = await fetch(path, {
    method, headers, body: body === undefined ? undefined : JSON.stringify(body),
  });
  const data = await r.json().catch(() => ({}));
  if (!r.ok) {
    const what = data.title ? `${data.title}: ${data.detail}` : `HTTP ${r.status}`;
    if (r.status === 401) needToken(what);
    else toast(what);
    throw new Error(what);
  }
  return data;
}

function command(method, path, body) {
  return api(method, path, body).catch(() => {});  // already shown as a toast
}

// -- the WebSocket -------------------------------------------------------------------------

function connect() {
  const proto = location.protocol === "https:" ? "wss:" : "ws:";
  const ws = new WebSocket(`${proto}//${location.host}/api/ws?client=dashboard`);
  state.ws = ws;
  ws.onopen = () => {
    if (state.tokens && state.token) ws.send(JSON.stringify({ auth: state.token }));
  };
  ws.onmessage = (ev) => handle(JSON.parse(ev.data));
  ws.onclose = () => {
    setLive(false);
    releaseAllJogs();
    state.ws = null;
    if (state.authorized) setTimeout(connect, 1000);
  };
}

function send(msg) {
  if (state.ws && state.ws.readyState === WebSocket.OPEN) {
    state.ws.send(JSON.stringify(msg));
    return true;
  }
  return false;
}

function setLive(live) {
  state.live = live;
  setConn(live ? "live" : "disconnected", live);
  document.querySelectorAll("button.jog").forEach((b) => { b.disabled = !live; });
}

function setConn(text, up) {
  const c = $("conn");
  c.textContent = text;
  c.className = `conn ${up ? "up" : "down"}`;
}

// -- who we are to the service ---------------------------------------------------------------

function setEstop(why) {
  // why: null when the E-STOP can act, else why it cannot (shown beside it)
  const b = $("estop");
  b.disabled = why !== null;
  b.title = why === null ? "Emergency stop: halts every axis" : `E-STOP disabled: ${why}`;
  $("estop-why").textContent = why === null ? "" : why;
}

async function authenticate() {
  // Ask the service at once whether it takes us (with the token we have, if any): it
  // answers 401 at once when it needs a token, rather than a WebSocket timing out.
  const headers = { "X-Drivebus-Client": "dashboard" };
  if (state.token) headers.Authorization = `Bearer ${state.token}`;
  let r;
  try {
    r = await fetch("/api/client", { headers });
  } catch (err) {
    setEstop("the service does not answer");
    setConn("unreachable", false);
    setTimeout(authenticate, 1000);
    return;
  }
  const data = await r.json().catch(() => ({}));
  if (r.status === 401) {
    needToken(state.token && data.title ? `${data.title}: ${data.detail}` : "");
    return;
  }
  if (!r.ok) {
    setEstop(`the service answered HTTP ${r.status}`);
    setTimeout(authenticate, 1000);
    return;
  }
  state.authorized = true;
  state.tokens = Boolean(data.tokens);
  $("login").hidden = true;
  $("login-error").textContent = "";
  hideToast();  // whatever a refused token said is over
  setEstop(null);
  setConn("connecting", false);
  if (!state.ws) connect();
}

function needToken(problem) {
  state.authorized = false;
  setEstop("log in first: this service needs a token");
  setConn("token needed", false);
  $("login-error").textContent = problem || "";
  $("login").hidden = false;
  $("token").focus();
  if (state.ws) state.ws.close();
}

function handle(msg) {
  switch (msg.type) {
    case "hello":
      state.scope = msg.scope;
      if (msg.clock) state.clockOffset = msg.clock.wall - msg.clock.monotonic;
      $("machine").textContent = msg.machine;
      $("who").textContent = `${msg.client} (${msg.scope})`;
      $("login").hidden = true;
      hideToast();
      send({ subscribe: ["axes", "lines", "motions", "errors"], max_rate: MAX_RATE });
      setLive(true);
      break;
    case "axis":
      onAxis(msg);
      break;
    case "line":
      onLine(msg);
      break;
    case "motion":
      markMotion(msg);
      note(`${msg.kind} ${msg.id} of ${msg.axes.join(", ")}: ${msg.event}` +
           (msg.error ? ` (${msg.error.type}: ${msg.error.message})` : ""), msg.event);
      break;
    case "lease":
      $("lease").textContent = msg.holder ? `lease: ${msg.holder}` : "lease: free";
      break;
    case "estop":
      note(`e-stop ${msg.event}`, "error");
      break;
    case "error":
      if (msg.axis) note(`axis ${msg.axis}: ${msg.state}` +
                         (msg.error ? ` (${msg.error.type}: ${msg.error.message})` : ""), "error");
      else if (msg.error) needToken(`${msg.error.title}: ${msg.error.detail}`);
      break;
    case "reply":
      if (!msg.ok && msg.error) toast(`${msg.op}: ${msg.error.title}: ${msg.error.detail}`);
      break;
    case "lost":
      note(`${msg.count} events lost (this page fell behind)`, "aborted");
      break;
    default:
      break;
  }
}

// -- axes ----------------------------------------------------------------------------------

function fmt(v, digits = 3) {
  return v === null || v === undefined ? "–" : Number(v).toFixed(digits);
}

function button(text, cls, onClick) {
  const b = document.createElement("button");
  b.type = "button";
  b.textContent = text;
  if (cls) b.className = cls;
  if (onClick) b.addEventListener("click", onClick);
  return b;
}

function jogButton(name, sign, speedInput) {
  const b = button(sign > 0 ? "▶" : "◀", "jog");
  b.id = `jog-${sign > 0 ? "plus" : "minus"}-${name}`;
  b.title = `hold to jog ${name} ${sign > 0 ? "+" : "−"}`;
  let timer = null;
  const release = () => {
    if (timer === null) return;
    clearInterval(timer);
    timer = null;
    state.jogs.delete(name);
    b.classList.remove("held");
    send({ jog: { axis: name, speed: 0 } });  // stop now, rather than at the TTL
  };
  const feed = () => {
    const speed = sign * Math.abs(parseFloat(speedInput.value) || 0);
    if (!send({ jog: { axis: name, speed, ttl: JOG_TTL } })) release();
  };
  b.addEventListener("pointerdown", (ev) => {
    if (!state.live || state.jogs.has(name)) return;
    ev.preventDefault();
    b.setPointerCapture(ev.pointerId);
    b.classList.add("held");
    timer = setInterval(feed, JOG_FEED);
    state.jogs.set(name, release);
    feed();
  });
  for (const type of ["pointerup", "pointercancel", "lostpointercapture"]) {
    b.addEventListener(type, release);
  }
  b.addEventListener("contextmenu", (ev) => ev.preventDefault());
  b.disabled = !state.live;
  return b;
}

function releaseAllJogs() {
  for (const release of [...state.jogs.values()]) release();
}

function addRow(name, msg) {
  const tr = document.createElement("tr");
  tr.id = `row-${name}`;
  const cell = (cls) => { const td = document.createElement("td"); if (cls) td.className = cls;
    tr.append(td); return td; };
  const nameCell = cell("name");
  nameCell.textContent = name;
  const small = document.createElement("small");
  small.textContent = `${msg.drive} · ${msg.line}@${msg.address}`;
  nameCell.append(small);
  cell().innerHTML = `<span class="state" id="state-${name}"></span>`;
  cell("num").id = `pos-${name}`;
  cell("num").id = `vel-${name}`;
  cell("alarm").id = `alarm-${name}`;

  const target = document.createElement("input");
  target.type = "number"; target.step = "any"; target.id = `target-${name}`;
  target.placeholder = "target";
  const moveCell = cell();
  const m = document.createElement("div"); m.className = "cell";
  m.append(target, button("Move", "", () => {
    const t = parseFloat(target.value);
    if (Number.isFinite(t)) command("POST", `/api/axes/${name}/move`, { target: t });
    else toast("move: enter a target position");
  }), button("Home", "", () => command("POST", `/api/axes/${name}/home`)));
  moveCell.append(m);

  const speed = document.createElement("input");
  speed.type = "number"; speed.step = "any"; speed.min = "0"; speed.value = "5";
  speed.id = `jogspeed-${name}`; speed.title = "jog speed (units/s)";
  const jogCell = cell();
  const j = document.createElement("div"); j.className = "cell";
  j.append(jogButton(name, -1, speed), speed, jogButton(name, +1, speed));
  jogCell.append(j);

  const stopCell = cell();
  const s = document.createElement("div"); s.className = "cell";
  const stop = button("Stop", "stop", () => command("POST", `/api/axes/${name}/stop`));
  stop.id = `stop-${name}`;
  s.append(stop, button("Reset", "", () => command("POST", `/api/axes/${name}/reset`)));
  stopCell.append(s);
  $("axes").tBodies[0].append(tr);
}

function onAxis(msg) {
  const name = msg.axis;
  if (!state.axes.has(name)) {
    addRow(name, msg);
    addAxisChart(name, msg);
  }
  state.axes.set(name, msg);
  const st = $(`state-${name}`);
  st.textContent = msg.state;
  st.className = `state ${msg.state}`;
  $(`pos-${name}`).textContent = fmt(msg.position);
  $(`vel-${name}`).textContent = fmt(msg.velocity, 2);
  const alarm = msg.alarm ? `${msg.alarm_code ?? ""} ${msg.alarm_text}`.trim()
    : (msg.error ? msg.error.type : "");
  $(`alarm-${name}`).textContent = alarm;
  const s = state.series.get(name);
  const t = wall(msg.timestamp);
  if (t !== null && (!s.t.length || t > s.t[s.t.length - 1])) {
    s.t.push(t); s.position.push(msg.position); s.velocity.push(msg.velocity);
    s.target.push(msg.target); s.state.push(msg.state);
    trim(s, ["t", "position", "velocity", "target", "state"]);
  }
}

// -- lines ---------------------------------------------------------------------------------

function onLine(msg) {
  onLineFacts(msg);
  onLineChart(msg);
}

function onLineFacts(msg) {
  let div = $(`line-${msg.name}`);
  if (!div) {
    div = document.createElement("div");
    div.className = "line";
    div.id = `line-${msg.name}`;
    div.innerHTML = `<div><b></b> <span class="facts"></span></div>
      <div class="bar"><div></div></div><div class="facts counters"></div>`;
    $("lines").append(div);
  }
  const pct = Math.round(msg.utilisation * 1000) / 10;
  div.querySelector("b").textContent = msg.name;
  div.querySelector("span.facts").textContent =
    `${msg.kind} ${msg.settings ?? ""} ${msg.endpoint} · ${pct}% busy`;
  div.querySelector(".bar div").style.width = `${Math.min(100, pct)}%`;
  div.querySelector(".counters").textContent =
    `${msg.transactions} transactions · ${msg.errors} errors · ${msg.retries} retries` +
    (msg.last_error ? ` · last: ${msg.last_error}` : "");
}

// -- charts --------------------------------------------------------------------------------

function wall(monotonic) {
  // The service's monotonic poll time on the wall clock (null before the first poll).
  if (!monotonic || state.clockOffset === null) return null;
  return monotonic + state.clockOffset;
}

function trim(s, keys) {
  const t = s.t;
  let n = 0;
  while (n < t.length && t[n] < t[t.length - 1] - KEEP) n++;
  if (n) for (const k of keys) s[k].splice(0, n);
}

function pause(on) {
  state.paused = on;
  $("pause").textContent = on ? "Resume" : "Pause";
  $("pause").classList.toggle("held", on);
  if (!on) draw();
}

function addAxisChart(name, msg) {
  state.series.set(name, { t: [], position: [], velocity: [], target: [], state: [],
                           marks: [] });
  const div = document.createElement("div");
  div.className = "chart";
  div.id = `chart-${name}`;
  $("charts").append(div);
  DrivebusCharts.axisChart(div, { name, unit: msg.units, time: true, height: 210,
                                  onZoom: () => pause(true) });
  DrivebusCharts.fit();  // the grid has re-flowed: every chart to its cell's width
}

function markMotion(msg) {
  const kinds = { started: "started", done: "in_position", aborted: "aborted",
                  failed: "error" };
  const now = Date.now() / 1000;
  for (const name of msg.axes || []) {
    const s = state.series.get(name);
    if (s) s.marks.push({ t: now, kind: kinds[msg.event] || "accepted", label: "" });
  }
}

function onLineChart(msg) {
  let s = state.lineSeries.get(msg.name);
  if (!s) {
    s = { t: [], utilisation: [], rate: [], latency: [], last: null };
    state.lineSeries.set(msg.name, s);
    const div = document.createElement("div");
    div.className = "chart";
    div.id = `linechart-${msg.name}`;
    $("line-charts").append(div);
    DrivebusCharts.lineChart(div, { name: msg.name, time: true, height: 180,
                                    onZoom: () => pause(true) });
    DrivebusCharts.fit();
  }
  const last = s.last;
  s.last = msg;
  const t = wall(msg.timestamp);
  if (!last || t === null || msg.timestamp <= last.timestamp) return;
  const dt = msg.timestamp - last.timestamp;
  const replies = msg.replies - last.replies;
  s.t.push(t);
  s.utilisation.push(Math.min(100, 100 * (msg.wire_time - last.wire_time) / dt));
  s.rate.push((msg.transactions - last.transactions) / dt);
  s.latency.push(replies > 0 ? 1000 * (msg.reply_time - last.reply_time) / replies : null);
  trim(s, ["t", "utilisation", "rate", "latency"]);
  const facts = document.querySelector(`#line-${CSS.escape(msg.name)} span.facts`);
  if (facts) {
    facts.textContent += ` · ${s.rate[s.rate.length - 1].toFixed(0)} tx/s` +
      (replies > 0 ? ` · reply ${s.latency[s.latency.length - 1].toFixed(2)} ms` : "");
  }
}

function visible(s, keys, from) {
  // The points inside the window (and one before, so the line enters from the edge).
  let i = 0;
  while (i < s.t.length && s.t[i] < from) i++;
  i = Math.max(0, i - 1);
  return keys.map((k) => s[k].slice(i));
}

function draw() {
  if (state.paused || state.clockOffset === null) return;
  const now = Date.now() / 1000;
  const from = now - state.window;
  for (const [name, s] of state.series) {
    const chart = DrivebusCharts.registry.get(`axis-${name}`);
    const data = visible(s, ["t", "position", "velocity", "target"], from);
    const [t, st] = visible(s, ["t", "state"], from);
    s.marks = s.marks.filter((m) => m.t >= now - KEEP);
    chart.set(data, { states: DrivebusCharts.stateRuns(t, st, now), marks: s.marks }, true);
    chart.u.setScale("x", { min: from, max: now });
  }
  for (const [name, s] of state.lineSeries) {
    const chart = DrivebusCharts.registry.get(`line-${name}`);
    chart.set(visible(s, ["t", "utilisation", "rate", "latency"], from), undefined, true);
    chart.u.setScale("x", { min: from, max: now });
  }
}

// -- recording -------------------------------------------------------------------------------

async function toggleRecording() {
  const b = $("record");
  if (state.recording === null) {
    const rec = await api("POST", "/api/recordings").catch(() => null);
    if (!rec) return;
    state.recording = rec.id;
    b.dataset.id = rec.id;
    b.textContent = "■ Stop and download";
    b.classList.add("held");
    const t0 = Date.now();
    clearInterval(toggleRecording.timer);
    toggleRecording.timer = setInterval(() => {
      $("recording").textContent = `recording ${rec.id}: ${((Date.now() - t0) / 1000).toFixed(0)} s`;
    }, 500);
    return;
  }
  const id = state.recording;
  state.recording = null;
  clearInterval(toggleRecording.timer);
  b.textContent = "● Record";
  b.classList.remove("held");
  await api("POST", `/api/recordings/${id}/stop`).catch(() => null);
  const headers = { "X-Drivebus-Client": "dashboard" };
  if (state.token) headers.Authorization = `Bearer ${state.token}`;
  const r = await fetch(`/api/recordings/${id}/report`, { headers });
  if (!r.ok) { toast(`recording ${id}: HTTP ${r.status}`); return; }
  const blob = await r.blob();
  const a = $("report-link");
  if (a.href) URL.revokeObjectURL(a.href);
  a.href = URL.createObjectURL(blob);
  a.download = `drivebus-${$("machine").textContent}-${id}.html`;
  a.textContent = `report ${id}`;
  a.hidden = false;
  a.dataset.id = id;
  $("recording").textContent = `recording ${id}: downloaded`;
  a.click();
}

// -- start ---------------------------------------------------------------------------------

$("login").addEventListener("submit", (ev) => {
  ev.preventDefault();
  state.token = $("token").value.trim();
  sessionStorage.setItem("drivebus-token", state.token);
  $("login-error").textContent = "";
  authenticate();
});

$("estop").addEventListener("click", () => {
  send({ estop: {} });                 // whichever path is up gets there first
  command("POST", "/api/estop");
  releaseAllJogs();
});

window.addEventListener("blur", releaseAllJogs);
document.addEventListener("visibilitychange", () => { if (document.hidden) releaseAllJogs(); });
$("window").addEventListener("change", () => {
  state.window = Number($("window").value);
  draw();
});
$("pause").addEventListener("click", () => pause(!state.paused));
$("record").addEventListener("click", toggleRecording);
window.addEventListener("resize", () => DrivebusCharts.fit());
DrivebusCharts.legend($("marks"));
setInterval(draw, DRAW_EVERY);
authenticate();
