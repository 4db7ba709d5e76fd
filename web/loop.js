// cutwatch dashboard: the residual loop closed from the page. Record the live source (or
// upload a log), analyse it in the background (POST /api/analyses), open the report,
// install its effects into the live observer, and compare the live error before and after.
// The live error is the force estimate minus the reference (the simulator's true force, or
// the log's / feed's f_ext): rms over the last ERR_WINDOW seconds of the stream, for the
// observer without and with the identified effects. Which channels those are, the hello
// says (their roles: reference, without_effects, with_effects; charts.js roles()).
import { roles } from "./charts.js";
import { request } from "./protocol.js";

const $ = (id) => document.getElementById(id);
const ERR_WINDOW = 5; // s of simulated time
const POLL_MS = 500;
const SETTLE = 1; // s after an install before the "after" window starts (filters settle)

const st = {
  roles: {}, // role -> channel name (from the hello)
  err: { t: [], fixed: [], effects: [] }, // recent errors (decimated stream samples)
  install: null, // {t, before: {fixed, effects}, after: null | {...}}
  job: null,
  recording: false,
};

// ---------------------------------------------------------------- REST
function say(msg) { $("loop-error").textContent = msg; }

// protocol.js's request, its refusal said on the loop's panel
async function api(method, path, body, raw = false) {
  try {
    return await request(method, path, body, raw);
  } catch (e) {
    say(e.message);
    throw e;
  }
}

// ---------------------------------------------------------------- live error
function rms(a) {
  let s = 0; let n = 0;
  for (const v of a) if (v !== null && Number.isFinite(v)) { s += v * v; n += 1; }
  return n ? Math.sqrt(s / n) : NaN;
}

function onFrame(msg) {
  const t = msg.t; const ch = msg.ch; const r = st.roles;
  const ft = ch[r.reference]; const ff = ch[r.without_effects]; const fe = ch[r.with_effects];
  if (!t.length || !ft || !ff || !fe) return;
  const e = st.err;
  if (e.t.length && t[0] < e.t[e.t.length - 1]) { e.t.length = 0; e.fixed.length = 0; e.effects.length = 0; }
  for (let i = 0; i < t.length; i++) {
    if (ft[i] === null || ff[i] === null || fe[i] === null) continue;
    e.t.push(t[i]); e.fixed.push(ff[i] - ft[i]); e.effects.push(fe[i] - ft[i]);
  }
  const tmin = t[t.length - 1] - ERR_WINDOW;
  let cut = 0;
  while (cut < e.t.length && e.t[cut] < tmin) cut++;
  if (cut) { e.t.splice(0, cut); e.fixed.splice(0, cut); e.effects.splice(0, cut); }
  const ins = st.install;
  // "after": a whole window, starting once the effects' filters have settled
  const tLast = e.t.length ? e.t[e.t.length - 1] : -Infinity;
  if (ins && !ins.after && tLast >= ins.t + SETTLE + ERR_WINDOW) ins.after = current(ins.t + SETTLE);
  showErrors();
}

// rms of the error's means over LEVEL_S bins: the force level, with the tooth-passing
// harmonics (100/200 Hz: whole periods in 50 ms) averaged out; the raw rms is dominated by
// the observers' dynamic error on those harmonics, the level by what the model lacks
const LEVEL_S = 0.05;
function levelRms(t, e) {
  const sums = new Map();
  for (let i = 0; i < t.length; i++) {
    if (!Number.isFinite(e[i])) continue;
    const k = Math.floor(t[i] / LEVEL_S + 1e-9);
    const b = sums.get(k) || [0, 0];
    b[0] += e[i]; b[1] += 1;
    sums.set(k, b);
  }
  // whole bins only: a bin cut by the window's edge holds a fraction of a harmonic period
  const full = Math.max(0, ...[...sums.values()].map(([, n]) => n));
  const means = [...sums.values()].filter(([, n]) => n >= 0.9 * full).map(([s, n]) => s / n);
  return rms(means);
}

function current(tmin = -Infinity) {
  const e = st.err;
  let i0 = 0;
  while (i0 < e.t.length && e.t[i0] < tmin) i0++;
  const t = e.t.slice(i0); const fixed = e.fixed.slice(i0); const effects = e.effects.slice(i0);
  return { fixed: rms(fixed), effects: rms(effects),
    fixedLevel: levelRms(t, fixed), effectsLevel: levelRms(t, effects) };
}

function cell(id, v) {
  const el = $(id);
  el.textContent = Number.isFinite(v) ? v.toPrecision(3) : "–";
  el.dataset.value = Number.isFinite(v) ? String(v) : "";
}

const NONE = { fixed: NaN, effects: NaN, fixedLevel: NaN, effectsLevel: NaN };

function showRow(row, v) {
  cell(`err-${row}-fixed`, v.fixed); cell(`err-${row}-effects`, v.effects);
  cell(`err-${row}-fixed-level`, v.fixedLevel); cell(`err-${row}-effects-level`, v.effectsLevel);
}

function showErrors() {
  showRow("now", current());
  const ins = st.install;
  showRow("before", ins ? ins.before : NONE);
  showRow("after", ins && ins.after ? ins.after : NONE);
  $("err-after-note").textContent = ins && !ins.after
    ? `measuring ${ERR_WINDOW} s from ${SETTLE} s after the install…` : "";
}

// ---------------------------------------------------------------- recording
async function refreshRecords() {
  const [rec, up] = await Promise.all([api("GET", "/api/records"), api("GET", "/api/uploads")]);
  const active = rec.records.find((r) => r.active);
  st.recording = Boolean(active);
  const btn = $("record");
  btn.textContent = active ? "Stop" : "Record";
  btn.dataset.state = active ? "recording" : "idle";
  // while recording: its progress; after: the "recorded ..." line stays (a refresh that
  // lands after the stop's answer must not wipe it), a recording line goes
  const status = $("record-status");
  if (active) {
    status.textContent =
      `● recording ${active.name}: ${(active.seconds || 0).toFixed(1)} s, ${active.samples} samples`;
  } else if (status.textContent.startsWith("●")) status.textContent = "";
  const sel = $("loop-log");
  const keep = sel.value;
  const opts = [
    ...rec.records.filter((r) => !r.active).map((r) => [JSON.stringify({ log: r.name, area: "recordings" }),
      `recording ${r.name} (${r.seconds === null ? "?" : r.seconds.toFixed(1)} s)`]),
    ...up.uploads.filter((u) => u.kind === "log").map((u) => [JSON.stringify({ log: u.name, area: "uploads" }),
      `upload ${u.name}`]),
  ];
  sel.replaceChildren(...opts.map(([v, text]) => {
    const o = document.createElement("option");
    o.value = v; o.textContent = text; o.selected = v === keep;
    return o;
  }));
  $("analyse").disabled = !opts.length || Boolean(st.job);
}

async function toggleRecord() {
  say("");
  const action = st.recording ? "stop" : "start";
  const r = await api("POST", "/api/record", { action });
  if (action === "stop") {
    const sel = $("loop-log");
    await refreshRecords();
    sel.value = JSON.stringify({ log: r.recording.name, area: "recordings" });
    $("record-status").textContent = `recorded ${r.recording.name}: ${r.recording.seconds.toFixed(1)} s (${r.recording.end})`;
  } else {
    await refreshRecords();
  }
}

// ---------------------------------------------------------------- uploads
async function upload(files) {
  say("");
  // a sidecar first: a CSV log is checked with it
  const sorted = [...files].sort((a, b) => (b.name.endsWith(".json") ? 1 : 0) - (a.name.endsWith(".json") ? 1 : 0));
  let last = null;
  for (const f of sorted) {
    const r = await api("POST", `/api/uploads?name=${encodeURIComponent(f.name)}`, f, true);
    if (r.kind === "log") last = r.name;
  }
  await refreshRecords();
  if (last) $("loop-log").value = JSON.stringify({ log: last, area: "uploads" });
}

// ---------------------------------------------------------------- analysis
async function analyse() {
  say("");
  const pick = JSON.parse($("loop-log").value);
  const holdout = Number($("loop-holdout").value);
  const job = await api("POST", "/api/analyses", { ...pick, holdout });
  st.job = job;
  $("analyse").disabled = true;
  $("install").disabled = true;
  $("report-link").hidden = true;
  showJob(job);
  const poll = async () => {
    const j = await api("GET", `/api/analyses/${job.id}`).catch(() => null);
    if (j) showJob(j);
    if (j && (j.state === "done" || j.state === "failed")) {
      st.job = null;
      $("analyse").disabled = false;
      return;
    }
    setTimeout(poll, POLL_MS);
  };
  setTimeout(poll, POLL_MS);
}

function showJob(j) {
  const p = $("analysis-progress");
  p.value = j.progress;
  p.dataset.state = j.state;
  const pct = `${Math.round(100 * j.progress)} %`;
  if (j.state === "failed") {
    $("analysis-status").textContent = `failed: ${j.message}`;
  } else if (j.state === "done") {
    const sel = j.selected.length ? j.selected.join(", ") : "none";
    const num = (v) => (v === null ? "–" : v.toPrecision(3));
    $("analysis-status").textContent =
      `done: ${j.report} — selected ${sel}; held-out rms ${num(j.rms_before)} → ${num(j.rms_after)}`;
    const a = $("report-link");
    a.href = j.report_url; a.hidden = false; a.textContent = `open report ${j.report}`;
    $("install").disabled = j.observer_effects === 0;
    $("install").dataset.report = j.report;
  } else {
    $("analysis-status").textContent = `${j.state} ${pct}${j.step ? `: ${j.step}` : ""}`;
  }
}

async function install() {
  say("");
  const report = $("install").dataset.report;
  const before = current();
  const r = await api("POST", "/api/observer-effects", { report });
  // the server's time of the install: the page may show the stream a little late
  st.install = { t: r.t, before, after: null };
  const names = r.observer_effects.map((e) => e.name).join(", ") || "none";
  const skipped = r.skipped.length ? ` (not live: ${r.skipped.join(", ")})` : "";
  $("installed").textContent = `installed: ${names}${skipped}`;
  showErrors();
}

async function uninstall() {
  say("");
  await api("DELETE", "/api/observer-effects");
  $("installed").textContent = "installed: none";
  st.install = null;
  showErrors();
}

function init() {
  window.addEventListener("cutwatch:hello", (ev) => { st.roles = roles(ev.detail.channels); });
  window.addEventListener("cutwatch:frame", (ev) => onFrame(ev.detail));
  $("record").onclick = () => toggleRecord().catch(() => {});
  $("loop-upload").onchange = (e) => upload(e.target.files).catch(() => {}).finally(() => { e.target.value = ""; });
  $("analyse").onclick = () => analyse().catch(() => { st.job = null; $("analyse").disabled = false; });
  $("install").onclick = () => install().catch(() => {});
  $("uninstall").onclick = () => uninstall().catch(() => {});
  const tick = () => refreshRecords().catch(() => {}).finally(() => setTimeout(tick, 1000));
  tick();
  showErrors();
}

init();
