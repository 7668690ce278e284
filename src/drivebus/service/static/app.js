// drivebus dashboard: live axes over WS /api/ws, commands over the public HTTP routes.
// Jog buttons are hold-to-run: pointer down starts a jog with a short TTL and feeds it
// over the WebSocket while held; release, leaving the button or losing the connection
// stops feeding (and sends speed 0), so the service's watchdog stops the axis anyway.
"use strict";

const JOG_TTL = 0.5;        // s: the axis stops this long after the last feed
const JOG_FEED = 150;       // ms between feeds while a jog button is held
const PLOT_WINDOW = 30;     // s of position history in the plot
const MAX_RATE = 20;        // axis/line updates per second: plenty for eyes and the plot
const COLORS = ["#58a6ff", "#3fb950", "#d29922", "#f778ba", "#a5d6ff", "#ff7b72", "#bc8cff"];

const state = {
  token: sessionStorage.getItem("drivebus-token") || "",
  ws: null,
  live: false,
  axes: new Map(),      // name -> last axis message
  history: new Map(),   // name -> [[t, position], ...]
  jogs: new Map(),      // name -> release() of its held jog button
  scope: "command",
};

const $ = (id) => document.getElementById(id);

function toast(text) {
  const t = $("toast");
  t.textContent = text;
  t.hidden = false;
  clearTimeout(toast.timer);
  toast.timer = setTimeout(() => { t.hidden = true; }, 5000);
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
    if (r.status === 401) showLogin();
    const what = data.title ? `${data.title}: ${data.detail}` : `HTTP ${r.status}`;
    toast(what);
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
    if (state.token) ws.send(JSON.stringify({ auth: state.token }));
  };
  ws.onmessage = (ev) => handle(JSON.parse(ev.data));
  ws.onclose = () => {
    setLive(false);
    releaseAllJogs();
    state.ws = null;
    setTimeout(connect, 1000);
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
  const c = $("conn");
  c.textContent = live ? "live" : "disconnected";
  c.className = `conn ${live ? "up" : "down"}`;
  document.querySelectorAll("button.jog").forEach((b) => { b.disabled = !live; });
}

function handle(msg) {
  switch (msg.type) {
    case "hello":
      state.scope = msg.scope;
      $("machine").textContent = msg.machine;
      $("who").textContent = `${msg.client} (${msg.scope})`;
      $("login").hidden = true;
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
      else if (msg.error) { toast(`${msg.error.title}: ${msg.error.detail}`); showLogin(); }
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
    state.history.set(name, []);
    drawLegend();
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
  if (msg.position !== null && msg.position !== undefined) {
    const h = state.history.get(name);
    const now = performance.now() / 1000;
    h.push([now, msg.position]);
    while (h.length && h[0][0] < now - PLOT_WINDOW) h.shift();
  }
}

// -- lines ---------------------------------------------------------------------------------

function onLine(msg) {
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

// -- the plot ------------------------------------------------------------------------------

function color(name) {
  return COLORS[[...state.history.keys()].indexOf(name) % COLORS.length];
}

function drawLegend() {
  $("legend").innerHTML = "";
  for (const name of state.history.keys()) {
    const span = document.createElement("span");
    span.innerHTML = `<i style="background:${color(name)}"></i>${name}`;
    $("legend").append(span);
  }
}

function draw() {
  const canvas = $("plot");
  const w = canvas.clientWidth, h = canvas.clientHeight;
  if (canvas.width !== w || canvas.height !== h) { canvas.width = w; canvas.height = h; }
  const g = canvas.getContext("2d");
  g.clearRect(0, 0, w, h);
  const now = performance.now() / 1000;
  let lo = Infinity, hi = -Infinity;
  for (const pts of state.history.values()) {
    for (const [, p] of pts) { lo = Math.min(lo, p); hi = Math.max(hi, p); }
  }
  if (!Number.isFinite(lo)) return;
  if (hi - lo < 1) { hi += 0.5; lo -= 0.5; }
  const pad = 28;
  const x = (t) => pad + (w - pad - 8) * (1 - (now - t) / PLOT_WINDOW);
  const y = (p) => h - pad / 2 - (h - pad) * (p - lo) / (hi - lo);
  g.strokeStyle = "#2c353f"; g.fillStyle = "#93a1ae"; g.font = "11px sans-serif";
  g.lineWidth = 1;
  for (let k = 0; k <= 4; k++) {
    const p = lo + (hi - lo) * k / 4;
    g.beginPath(); g.moveTo(pad, y(p)); g.lineTo(w, y(p)); g.stroke();
    g.fillText(p.toFixed(0), 2, y(p) + 4);
  }
  g.lineWidth = 2;
  for (const [name, pts] of state.history) {
    if (!pts.length) continue;
    g.strokeStyle = color(name);
    g.beginPath();
    pts.forEach(([t, p], i) => (i ? g.lineTo(x(t), y(p)) : g.moveTo(x(t), y(p))));
    g.lineTo(x(now), y(pts[pts.length - 1][1]));  // it is still there now
    g.stroke();
  }
}

// -- start ---------------------------------------------------------------------------------

function showLogin() {
  $("login").hidden = false;
}

$("login").addEventListener("submit", (ev) => {
  ev.preventDefault();
  state.token = $("token").value.trim();
  sessionStorage.setItem("drivebus-token", state.token);
  $("login").hidden = true;
  if (state.ws) state.ws.close(); else connect();
});

$("estop").addEventListener("click", () => {
  send({ estop: {} });                 // whichever path is up gets there first
  command("POST", "/api/estop");
  releaseAllJogs();
});

window.addEventListener("blur", releaseAllJogs);
document.addEventListener("visibilitychange", () => { if (document.hidden) releaseAllJogs(); });
$("window").textContent = PLOT_WINDOW;
setInterval(draw, 100);
connect();
