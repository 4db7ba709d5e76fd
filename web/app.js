// cutwatch dashboard: WebSocket stream -> uPlot charts; controls through the REST API.
// The message schema lives in protocol.js (its twin is server/service/messages.py). The
// charts are built from the stream's own description (the hello: charts, channels, parts;
// charts.js): no channel's name is written in web/.
import { checkMessage, request } from "./protocol.js";
import { accuracyTable, accuracyTitle, parameterChannels, parameterRows } from "./panels.js";
import { PAGES, PALETTE, chartSpecs, forceLooks } from "./charts.js";
import { TIMELINE_HEAD, ackRefusal, eventRow, headline, markersIn, mergeEvent, ordered,
  statusView } from "./monitor.js";

const uPlot = window.uPlot;
const $ = (id) => document.getElementById(id);

const COLORS = { lag: "#cc3311", rtf: "#0072b2" };
const HEALTH_WINDOW = 60; // wall seconds
const ACCURACY_WINDOW = 60; // s of simulated time in the accuracy history chart

const state = {
  ws: null, retry: 0, charts: {}, specs: {}, data: {}, zoomed: {}, channels: [], frames: 0,
  dropped: 0, dirty: false, grid: {}, health: { x: [], lag: [], rtf: [] }, healthChart: null,
  labels: {}, acc: { chart: null, key: "", data: [[]] },
  events: new Map(), role: null, status: null, layout: "",
  params: { names: [], latest: {}, key: "", t: -Infinity }, hello: null,
};

// ---------------------------------------------------------------- charts
// tick labels that stay distinct for small parameters (an inertia ~ 1e-4 kg m^2)
function fmt(v) {
  if (v === 0) return "0";
  const a = Math.abs(v);
  return a < 1e-2 || a >= 1e4 ? v.toExponential(2) : String(Number(v.toPrecision(4)));
}

function width(el) {
  return Math.max(200, el.clientWidth || 400);
}

function makeChart(spec) {
  const id = spec.id;
  const el = $(`chart-${id}`);
  const opts = {
    width: width(el), height: spec.wide ? 260 : 170,
    scales: { x: { time: false } },
    axes: [{ label: "t [s]" }, { size: 70, values: (u, vals) => vals.map(fmt) },
      ...(spec.scale ? [{ scale: spec.scale, side: 1, size: 50,
        values: (u, vals) => vals.map(fmt) }] : [])],
    legend: { live: true },
    cursor: { drag: { x: true, y: false } },
    series: [{ label: "t" }, ...spec.series.map(([, label, color, scale, o = {}]) => ({
      label, stroke: color, width: o.width ?? 1.4, points: { show: false },
      ...(scale ? { scale } : {}), ...(o.dash ? { dash: o.dash } : {}),
      // a parameter the data do not determine is not shown as a number
      ...(o.notExcited ? { value: (u, v) => (v == null ? "–" : "not excited") } : {}),
    }))],
    bands: spec.bands || [],
    hooks: {
      setSelect: [(u) => { if (u.select.width > 0) state.zoomed[id] = true; }],
      ...(spec.markers ? { draw: [(u) => drawMarkers(u, id)] } : {}),
    },
  };
  const empty = [[], ...spec.series.map(() => [])];
  const chart = new uPlot(opts, empty, el);
  el.addEventListener("dblclick", () => { state.zoomed[id] = false; });
  state.charts[id] = chart;
  state.data[id] = empty;
  state.zoomed[id] = false;
}

// A chart's panel: its title (with the "not excited" flag of an identified parameter)
// and the element uPlot draws in.
function panel(spec) {
  const sec = document.createElement("section");
  sec.className = spec.wide ? "panel wide" : "panel";
  sec.id = `panel-${spec.id}`;
  const h = document.createElement("h2");
  h.textContent = spec.title;
  if (spec.excited) {
    const flag = document.createElement("span");
    flag.id = `flag-${spec.id}`;
    flag.className = "flag";
    flag.hidden = true;
    flag.textContent = "not excited";
    h.append(" ", flag);
  }
  const div = document.createElement("div");
  div.id = `chart-${spec.id}`;
  div.className = "chart";
  sec.append(h, div);
  return sec;
}

// A chart whose part does not run: its title and the part's reason, no chart.
function downPanel(spec, reason) {
  const sec = document.createElement("section");
  sec.className = "panel down";
  sec.id = `panel-${spec.id}`;
  sec.dataset.part = spec.part;
  const h = document.createElement("h2");
  h.textContent = spec.title;
  const p = document.createElement("p");
  p.className = "token";
  p.textContent = `not running: the ${spec.part} part ${reason}`;
  sec.append(h, p);
  return sec;
}

// On hello (and when a part stops or starts): the charts the stream describes, on their
// pages, those of a part that does not run as its reason; built again only when they
// change (a new part, another pipeline, a part's state).
function buildCharts(msg, parts) {
  const down = new Map((parts || []).filter((p) => !p.running).map((p) => [p.name, p.reason]));
  const specs = chartSpecs(msg);
  const layout = JSON.stringify([specs, [...down.keys()]]);
  if (layout === state.layout) return false;
  state.layout = layout;
  for (const c of Object.values(state.charts)) c.destroy();
  state.charts = {}; state.specs = {}; state.data = {}; state.zoomed = {};
  const isDown = (spec) => spec.part && down.has(spec.part);
  for (const page of PAGES) {
    const mine = specs.filter((s) => s.page === page);
    $(`charts-${page}`).replaceChildren(...mine.filter((s) => !isDown(s)).map(panel),
      ...mine.filter(isDown).map((s) => downPanel(s, down.get(s.part))));
    $(`page-${page}`).hidden = mine.length === 0;
  }
  const nr = specs.filter((s) => s.page === "research" && !isDown(s)).length;
  $("tab-research-count").textContent = nr ? `(${nr} charts)` : "";
  for (const spec of specs.filter((s) => !isDown(s))) {
    state.specs[spec.id] = spec;
    makeChart(spec);
  }
  return true;
}

// A vertical line at each event in the chart's x range, on top of the series: red while
// the event waits for an acknowledgement, grey after. The chart's element says what it drew
// (data-markers: how many; data-marker-px: their x in canvas pixels; data-marker-ids).
function drawMarkers(u, id) {
  const el = $(`chart-${id}`);
  const t0 = u.scales.x.min;
  const t1 = u.scales.x.max;
  const ms = t0 == null || t1 == null ? [] : markersIn(state.events, t0, t1);
  const { top, height } = u.bbox;
  const ctx = u.ctx;
  const w = Math.max(3, Math.round(2 * (window.devicePixelRatio || 1)));
  const xs = ms.map((m) => {
    const x = Math.round(u.valToPos(m.t, "x", true));
    ctx.fillStyle = m.color;
    ctx.fillRect(x - Math.floor(w / 2), top, w, height);
    return x;
  });
  el.dataset.markers = String(ms.length);
  el.dataset.markerPx = xs.join(",");
  el.dataset.markerIds = ms.map((m) => m.id).join(",");
}

function makeHealthChart() {
  const el = $("chart-health");
  state.healthChart = new uPlot({
    width: width(el), height: 130, scales: { x: { time: true }, rtf: { auto: true } },
    axes: [{}, { label: "lag [ms]", size: 55 }, { scale: "rtf", side: 1, label: "rt factor", size: 55 }],
    series: [{}, { label: "lag [ms]", stroke: COLORS.lag, points: { show: false } },
      { label: "real-time factor", stroke: COLORS.rtf, scale: "rtf", points: { show: false } }],
  }, [[], [], []], el);
}

function clearData() {
  for (const [id, spec] of Object.entries(state.specs)) {
    state.data[id] = [[], ...spec.series.map(() => [])];
  }
}

function append(frame) {
  if (!frame.t.length) return;
  for (const [id, spec] of Object.entries(state.specs)) {
    const d = state.data[id];
    const t = frame[state.grid[spec.series[0][0]] || "ts"];
    if (!t.length) continue;
    // a reset (time going back) starts the chart again
    if (d[0].length && t[0] < d[0][d[0].length - 1]) {
      for (const arr of d) arr.length = 0;
    }
    d[0].push(...t);
    spec.series.forEach(([ch, , , , o], i) => {
      const v = frame.ch[ch];
      const m = o && o.mask && frame.ch[o.mask[0]];
      if (!v) d[i + 1].push(...t.map(() => null));
      else if (m) d[i + 1].push(...v.map((x, j) => (m[j] === o.mask[1] ? x : null)));
      else d[i + 1].push(...v);
    });
    const tmin = t[t.length - 1] - spec.window_s;
    let cut = 0;
    while (cut < d[0].length && d[0][cut] < tmin) cut++;
    if (cut) for (const arr of d) arr.splice(0, cut);
  }
}

function redraw() {
  for (const [id, chart] of Object.entries(state.charts)) {
    chart.setData(state.data[id], !state.zoomed[id]);
  }
  const h = state.health;
  state.healthChart.setData([h.x, h.lag, h.rtf]);
  if (state.acc.chart) state.acc.chart.setData(state.acc.data);
}

function resize() {
  for (const [id, chart] of Object.entries(state.charts)) {
    chart.setSize({ width: width($(`chart-${id}`)), height: chart.height });
  }
  state.healthChart.setSize({ width: width($("chart-health")), height: state.healthChart.height });
  const ac = state.acc.chart;
  if (ac) ac.setSize({ width: width($("chart-accuracy")), height: ac.height });
}

// The latest excited flag of each identified parameter: "not excited" shown while it is 0.
function showExcited(frame) {
  for (const [id, spec] of Object.entries(state.specs)) {
    if (!spec.excited) continue;
    const v = frame.ch[spec.excited];
    const flag = document.getElementById(`flag-${id}`);
    if (!v || !v.length || !flag) continue;
    const last = v[v.length - 1];
    flag.hidden = last !== 0;
    flag.dataset.excited = String(last);
  }
}

// The parts of the pipeline: running, or why not (hello and every frame); the charts of
// a part that stopped or started again are rebuilt.
function showParts(parts) {
  const key = JSON.stringify(parts || []);
  const el = $("parts");
  if (el.dataset.key === key) return;
  el.dataset.key = key;
  if (state.hello && buildCharts(state.hello, parts)) clearData();
  el.replaceChildren(...(parts || []).map((p) => {
    const tr = document.createElement("tr");
    tr.dataset.part = p.name;
    tr.dataset.running = String(p.running);
    for (const text of [p.name, p.running ? "running" : "not running", p.reason]) {
      const td = document.createElement("td");
      td.textContent = text;
      tr.append(td);
    }
    return tr;
  }));
  const down = (parts || []).filter((p) => !p.running).length;
  $("parts-summary").textContent = down ? `${down} not running` : "all running";
}

// ---------------------------------------------------------------- pages
// The page the address names: #research, else the machine's (#operator). The charts drawn
// while their page was hidden take their width when it shows.
function showPage() {
  const page = location.hash === "#research" ? "research" : "operator";
  document.body.dataset.page = page;
  for (const p of PAGES) {
    const tab = $(`tab-${p}`);
    if (p === page) tab.setAttribute("aria-current", "page");
    else tab.removeAttribute("aria-current");
  }
  resize();
}

// ---------------------------------------------------------------- identified parameters
// The latest finite value of each channel the parameters' table reads (a reset, time
// going back, forgets them), and the table redrawn when its text changes.
function showParams(frame) {
  const p = state.params;
  if (frame) {
    if (frame.health && frame.health.sim_t < p.t) p.latest = {};
    if (frame.health) p.t = frame.health.sim_t;
    for (const name of p.names) {
      const v = frame.ch[name];
      if (!v) continue;
      for (let i = v.length - 1; i >= 0; i--) {
        if (v[i] != null) { p.latest[name] = v[i]; break; }
      }
    }
  }
  const rows = parameterRows(state.channels, p.latest);
  const key = JSON.stringify(rows);
  if (key === p.key) return;
  p.key = key;
  const cells = (r) => [r.label, r.value, r.interval, r.unit];
  $("params").innerHTML = rows.length ? "<thead><tr><th>parameter</th><th>estimate</th>" +
    "<th>95 % interval</th><th>unit</th></tr></thead>" : "";
  const body = document.createElement("tbody");
  body.append(...rows.map((r) => {
    const tr = document.createElement("tr");
    tr.dataset.key = r.key;
    tr.dataset.excited = String(r.excited);
    for (const text of cells(r)) {
      const td = document.createElement("td");
      td.textContent = text;
      td.dataset.excited = r.excited === false ? "0" : "1";
      tr.append(td);
    }
    return tr;
  }));
  if (rows.length) $("params").append(body);
  $("params-empty").hidden = rows.length > 0;
}

// ---------------------------------------------------------------- accuracy panel
function accuracyChart(acc) {
  const force = forceLooks(state.channels);
  const names = Object.keys(acc.rms);
  const el = $("chart-accuracy");
  if (state.acc.chart) state.acc.chart.destroy();
  el.replaceChildren();
  const truth = acc.mode === "truth";
  const floor = truth ? [{ label: "Q(s)·truth", stroke: "#888888", dash: [5, 4], width: 1.2,
    points: { show: false } }] : [];
  state.acc.chart = new uPlot({
    width: width(el), height: 190, scales: { x: { time: false } },
    axes: [{ label: "t [s]" }, { label: `rms ${acc.windows[0]} s [N m]`, size: 60,
      values: (u, vals) => vals.map(fmt) }],
    legend: { live: true },
    series: [{ label: "t" }, ...names.map((k, i) => ({
      label: (force[k] || [state.labels[k] || k])[0],
      stroke: (force[k] && force[k][1]) || PALETTE[i % PALETTE.length],
      width: 1.4, points: { show: false } })), ...floor],
  }, [[], ...names.map(() => []), ...floor.map(() => [])], el);
  state.acc.data = [[], ...names.map(() => []), ...floor.map(() => [])];
}

function showAccuracy(acc, simT) {
  const key = `${acc.mode}|${Object.keys(acc.rms).join(",")}`;
  if (key !== state.acc.key) { state.acc.key = key; accuracyChart(acc); }
  const title = $("accuracy-title");
  title.textContent = accuracyTitle(acc);
  title.dataset.mode = acc.mode;
  const { head, rows } = accuracyTable(acc, state.labels);
  const th = head.map((h) => `<th>${h}</th>`).join("");
  const tr = rows.map((r) => `<tr data-key="${r.key}"><td>${r.label}</td>` +
    r.cells.map((c, i) => `<td data-col="${i}">${c}</td>`).join("") + "</tr>").join("");
  $("accuracy").innerHTML = `<thead><tr>${th}</tr></thead><tbody>${tr}</tbody>`;
  // history of the shortest window's rms, on simulated time
  const d = state.acc.data;
  const x = d[0];
  if (x.length && simT < x[x.length - 1]) for (const a of d) a.length = 0;  // a reset
  if (x.length && simT === x[x.length - 1]) return;  // paused: the same numbers again
  x.push(simT);
  const vals = Object.values(acc.rms).map((v) => v[0]);
  if (acc.mode === "truth") vals.push(acc.floor[0]);
  vals.forEach((v, i) => d[i + 1].push(v));
  let cut = 0;
  while (cut < x.length && x[cut] < simT - ACCURACY_WINDOW) cut++;
  if (cut) for (const a of d) a.splice(0, cut);
}

// ---------------------------------------------------------------- health
function showHealth(h) {
  const now = Date.now() / 1000;
  const hh = state.health;
  hh.x.push(now); hh.lag.push(h.lag_ms); hh.rtf.push(h.realtime_factor);
  while (hh.x.length && hh.x[0] < now - HEALTH_WINDOW) { hh.x.shift(); hh.lag.shift(); hh.rtf.shift(); }
  $("simt").textContent = `t = ${h.sim_t.toFixed(2)} s${h.paused ? " (paused)" : ""}`;
  $("simt").dataset.simT = String(h.sim_t);
  const rows = [
    ["real-time factor", h.realtime_factor.toFixed(3)],
    ["speed", h.paused ? "paused" : `${h.speed}×`],
    ["loop lag", `${h.lag_ms.toFixed(2)} ms (p99 ${h.lag_p99_ms.toFixed(2)} ms)`],
    ["clients", h.clients],
    ["frames dropped (all clients)", h.dropped_total],
    ["frames dropped (this page)", state.dropped],
    ["stalls", h.stalls],
  ];
  $("health").innerHTML = rows.map(([k, v]) => `<tr><td>${k}</td><td>${v}</td></tr>`).join("");
  $("pause").disabled = h.paused;
  $("resume").disabled = !h.paused;
}

// ---------------------------------------------------------------- REST
// the session is an HttpOnly cookie the browser sends by itself (log in at /login);
// protocol.js's request sends a closed one (401) back to the login page

async function showSession() {
  const s = await fetch("/api/session").then((r) => r.json());
  if (s.access_control && !s.role) { location.assign("/login"); return; }
  $("session").textContent = s.access_control ? `signed in: ${s.role}` : "";
  state.role = s.role;
  renderTimeline();
  $("logout").hidden = !s.access_control;
}

async function call(method, path, body) {
  $("error").textContent = "";
  try {
    return await request(method, path, body);
  } catch (e) {
    $("error").textContent = e.message;
    throw e;
  }
}

const control = (action, extra = {}) => call("POST", "/api/control", { action, ...extra });

// A knob of the running pipeline's parts (GET /api/params): its doc and the parts that
// read it in the label's title; one whose parts are paused is greyed (data-waiting),
// its reason in the title: a value set then is kept for when they run.
function knobControl(name, k) {
  const label = document.createElement("label");
  label.textContent = name.replaceAll("_", " ");
  const named = { simulator: "the simulated stage", spindle_steps: "the scenario's spindle steps" };
  const parts = (k.parts || []).map((p) => named[p] || `the ${p} part`);
  label.title = [k.doc, parts.length ? `read by ${parts.join(" and ")}` : "", k.waiting || ""]
    .filter(Boolean).join("\n");
  label.htmlFor = `knob-${name}`;
  label.dataset.waiting = k.waiting ? "true" : "false";
  const out = document.createElement("output");
  let input;
  if (k.type === "choice") {
    input = document.createElement("select");
    input.replaceChildren(...k.choices.map((c) => {
      const o = document.createElement("option");
      o.value = c; o.textContent = c; o.selected = c === k.value;
      return o;
    }));
    input.addEventListener("change", () => call("PATCH", "/api/params", { [name]: input.value }));
  } else if (k.type === "bool") {
    input = document.createElement("input");
    input.type = "checkbox";
    input.checked = k.value;
    out.textContent = "";
    input.addEventListener("change", () => call("PATCH", "/api/params", { [name]: input.checked })
      .catch(() => { input.checked = !input.checked; }));
  } else {
    input = document.createElement("input");
    input.type = "range";
    input.min = k.min; input.max = k.max;
    input.step = "any";
    input.value = k.value;
    const show = () => { out.textContent = `${Number(input.value).toPrecision(3)} ${k.unit}`; };
    show();
    input.addEventListener("input", show);
    input.addEventListener("change", () => call("PATCH", "/api/params", { [name]: Number(input.value) }));
  }
  input.id = `knob-${name}`;
  input.name = name;
  return [label, input, out];
}

async function loadViser() {
  const h = await fetch("/api/health").then((r) => r.json());
  if (!h.viser_running) return;
  // viser itself listens on the server's loopback only: the app relays it at /viser/,
  // behind this page's session
  const url = new URL("/viser/", location.href).href;
  const frame = $("viser");
  if (frame.src !== url) frame.src = url;
  $("viser-link").href = url;
  $("viser-panel").hidden = false;
}

async function loadControls() {
  const [params, sc] = await Promise.all([
    fetch("/api/params").then((r) => r.json()), fetch("/api/scenarios").then((r) => r.json())]);
  // each knob on the page it names (page: an operator's on the machine's tab, the rest on
  // the research tab), the same controls and the same PATCH on both
  const entries = Object.entries(params);
  const on = (page) => entries.filter(([, k]) => (k.page || "research") === page)
    .flatMap(([n, k]) => knobControl(n, k));
  const operator = on("operator");
  $("knobs-operator").replaceChildren(...operator);
  $("knobs-operator-panel").hidden = !operator.length;
  const rows = on("research");
  if (!rows.length) {
    const none = document.createElement("p");
    none.className = "stat";
    none.textContent = operator.length
      ? "No part of this machine reads a research knob (its operator's are on the machine's tab)."
      : "No part of this machine reads a knob.";
    rows.push(none);
  }
  $("knobs").replaceChildren(...rows);
  const sel = $("scenario");
  sel.replaceChildren(...Object.entries(sc.scenarios).map(([name, doc]) => {
    const o = document.createElement("option");
    o.value = name; o.textContent = name; o.title = doc; o.selected = name === sc.current;
    return o;
  }));
}

function syncKnobs(knobs) {
  for (const [name, v] of Object.entries(knobs)) {
    const el = document.getElementById(`knob-${name}`);
    if (!el || el === document.activeElement) continue;
    if (el.type === "checkbox") el.checked = v;
    else if (el.tagName === "SELECT") el.value = v;
    else if (Number(el.value) !== v) { el.value = v; el.dispatchEvent(new Event("input")); }
  }
}

// ---------------------------------------------------------------- process monitor
// The status strip from the frame's MonitorStatus (a stream without one: monitor off).
function showStatus(st) {
  state.status = st || null;
  const v = statusView(st, headline(state.events));
  const strip = $("strip");
  if (strip.dataset.state !== v.state) strip.dataset.state = v.state;
  const set = (id, text) => { const el = $(id); if (el.textContent !== text) el.textContent = text; };
  set("strip-state", v.label);
  set("strip-tool", v.tool);
  set("strip-wearof", v.wearOf);
  set("strip-weartool", v.wearTool);
  set("strip-wear", v.wear);
  set("strip-wearlimit", v.wearLimit);
  const group = $("strip-weargroup");
  if (group.dataset.apart !== String(v.wearApart)) group.dataset.apart = String(v.wearApart);
  if (group.hidden === v.wearKnown) group.hidden = !v.wearKnown;
  set("strip-life", v.life);
  set("strip-where", v.where);
  set("strip-unacked", v.unackedText);
  set("strip-message", v.message);
  const bar = $("strip-wearbar");
  bar.style.width = `${(100 * v.wearBar).toFixed(1)}%`;
  bar.className = v.wearBar >= 1 ? "over" : v.wearBar >= 0.8 ? "high" : "";
}

// The timeline, newest first, with an Acknowledge button on each event not yet
// acknowledged (disabled, saying why, for anyone but an operator).
function renderTimeline() {
  const why = ackRefusal(state.role);
  const rows = ordered(state.events).map(eventRow);
  $("timeline-rows").replaceChildren(...rows.map((r) => {
    const tr = document.createElement("tr");
    tr.dataset.id = r.id;
    tr.dataset.kind = r.kind;
    tr.className = r.waiting ? "waiting" : r.cells[7] === "no" ? "" : "acked";
    tr.title = r.message;
    r.cells.forEach((c, i) => {
      const td = document.createElement("td");
      td.textContent = c;
      if (i === 7 && c === "no") {
        const b = document.createElement("button");
        b.type = "button";
        b.className = "ack";
        b.textContent = "Acknowledge";
        b.disabled = Boolean(why);
        b.title = why || "acknowledge this event (POST /api/events/{id}/ack)";
        b.onclick = () => acknowledge(r.id).catch(() => {});
        td.textContent = "";
        td.append(b);
      }
      tr.append(td);
    });
    return tr;
  }));
  $("timeline-empty").hidden = rows.length > 0;
  const open = rows.filter((r) => r.cells[7] === "no").length;
  $("ack-all").disabled = Boolean(why) || open === 0;
  $("ack-all").title = why || "acknowledge every event listed as not acknowledged";
  $("ack-why").textContent = why;
  if (state.status) showStatus(state.status);
}

async function acknowledge(id) {
  $("ack-error").textContent = "";
  let j;
  try {
    j = await request("POST", `/api/events/${encodeURIComponent(id)}/ack`, {});
  } catch (e) {
    $("ack-error").textContent = `acknowledge ${id}: ${e.message}`;
    throw new Error($("ack-error").textContent);
  }
  if (j && j.id && mergeEvent(state.events, j)) { renderTimeline(); state.dirty = true; }
  return j;
}

async function acknowledgeAll() {
  for (const ev of ordered(state.events)) {
    if (!ev.acked) await acknowledge(ev.id).catch(() => {});
  }
}

// The events kept so far: the history (GET /api/events) where the service has one, the
// snapshot's latest otherwise.
async function loadEvents() {
  let items = null;
  const r = await fetch("/api/events?limit=100");
  if (r.ok) items = (await r.json()).items;
  else {
    const s = await fetch("/api/snapshot").then((x) => (x.ok ? x.json() : {}));
    items = s.events || (s.pipeline && s.pipeline.events) || [];
  }
  let changed = false;
  for (const ev of items || []) changed = mergeEvent(state.events, ev) || changed;
  if (changed) { renderTimeline(); state.dirty = true; }
}

// ---------------------------------------------------------------- stream
function connect() {
  const proto = location.protocol === "https:" ? "wss" : "ws";
  const ws = new WebSocket(`${proto}://${location.host}/ws`);
  state.ws = ws;
  const conn = $("conn");
  ws.onopen = () => { state.retry = 0; };
  ws.onmessage = (ev) => {
    let msg;
    try { msg = checkMessage(ev.data); } catch (e) { $("error").textContent = e.message; return; }
    if (msg.type === "event") {
      if (mergeEvent(state.events, msg.event)) { renderTimeline(); state.dirty = true; }
      return;
    }
    if (msg.type === "hello") {
      state.channels = msg.channels;
      state.grid = Object.fromEntries(msg.channels.map((c) => [c.name, c.grid]));
      state.labels = Object.fromEntries(msg.channels.map((c) => [c.name, c.label]));
      state.hello = msg;
      buildCharts(msg, msg.parts);
      clearData();
      state.params = { names: parameterChannels(msg.channels), latest: {}, key: "", t: -Infinity };
      showParams(null);
      showParts(msg.parts);
      window.dispatchEvent(new CustomEvent("cutwatch:hello", { detail: msg })); // loop.js
      conn.textContent = `live · ${msg.scenario}`;
      conn.className = "conn up";
      conn.dataset.state = "up";
      loadControls().catch((e) => { $("error").textContent = e.message; });
      loadViser().catch(() => {});
      loadEvents().catch((e) => { $("ack-error").textContent = e.message; });
      return;
    }
    state.frames += 1;
    state.dropped += msg.dropped;
    append(msg);
    window.dispatchEvent(new CustomEvent("cutwatch:frame", { detail: msg })); // loop.js
    state.dirty = true;
    showHealth(msg.health);
    showStatus(msg.status);
    showExcited(msg);
    showAccuracy(msg.accuracy, msg.health.sim_t);
    showParts(msg.parts);
    showParams(msg);
    syncKnobs(msg.knobs);
    document.body.dataset.frames = String(state.frames);
  };
  ws.onclose = () => {
    conn.textContent = "disconnected — reconnecting…";
    conn.className = "conn down";
    conn.dataset.state = "down";
    const delay = Math.min(5000, 500 * 2 ** state.retry);
    state.retry += 1;
    setTimeout(connect, delay);
  };
  ws.onerror = () => ws.close();
}

function frameLoop() {
  if (state.dirty) { state.dirty = false; redraw(); }
  requestAnimationFrame(frameLoop);
}

function init() {
  $("timeline-head").replaceChildren(...TIMELINE_HEAD.map((h) => {
    const th = document.createElement("th");
    th.textContent = h;
    return th;
  }));
  $("ack-all").onclick = () => acknowledgeAll();
  renderTimeline();
  makeHealthChart();
  window.addEventListener("hashchange", showPage);
  showPage();
  $("pause").onclick = () => control("pause");
  $("resume").onclick = () => control("resume");
  $("reset").onclick = () => control("reset");
  $("speed").onchange = (e) => control("speed", { value: Number(e.target.value) });
  $("scenario").onchange = (e) => control("scenario", { scenario: e.target.value })
    .then((r) => { $("conn").textContent = `live · ${r.scenario}`; clearData(); return loadControls(); })
    .catch(() => {});
  $("logout").onclick = () => fetch("/api/logout", { method: "POST" })
    .then(() => location.assign("/login"));
  showSession().catch(() => {});
  window.addEventListener("resize", resize);
  connect();
  requestAnimationFrame(frameLoop);
}

init();
