// Pure helpers of the process monitor's parts of the dashboard (no DOM): the status strip's
// words, the event timeline's rows, the chart markers.
// tests/service/test_monitor_ui.py runs them under node; app.js draws what they return.

// the monitor's states as the strip shows them (big, across the shop)
export const STATE_WORDS = {
  off: "OFF", teaching: "TEACHING", watching: "WATCHING", alarm: "ALARM",
};
// event kinds in words
export const KIND_WORDS = {
  breakage: "tool breakage", collision: "collision / overload", missing_tool: "missing tool",
  wear_limit: "wear limit", life_short: "tool life short",
};
// actions in words
export const ACTION_WORDS = { feed_hold: "feed hold", alarm: "alarm", notice: "notice" };
// the colour of an event's marker on the charts: red while it waits for an operator
export const MARKER_ALARM = "#e00000";
export const MARKER_DONE = "#8a8f98";

const dash = "–";

function num(v, digits) {
  return v === null || v === undefined || !Number.isFinite(Number(v)) ? null
    : Number(v).toFixed(digits);
}

// A tool's words: the CNC's T-number when it is the spindle's tool (a part program
// names it), else the wear model's own count ("tool 3").
export function toolText(n, cnc = true) {
  if (!n) return dash;
  return cnc ? `T${n}` : `tool ${n}`;
}

// The strip's fields for a MonitorStatus (SCHEMA.status); a frame without one (a stream
// without the process monitor) shows the monitor off. `latest`: the newest event still
// waiting for an acknowledgement (its message is shown while in alarm), or null.
// Issue 28: the wear tiles speak of one tool (`wear_tool`) from one source: its share of
// one stated limit and the alarm's threshold as a share of that limit. When that tool is
// not the spindle's (`wear_of` names it: today's default scenario runs seed 004's
// turning tool beside the milling machine), the wear tiles are their own labelled group
// with their own tool number.
export function statusView(status, latest = null) {
  const s = status || { state: "off", tool: 0, program: "", line: 0, part: -1,
    wear_share: null, life_left_min: null, unacked: 0 };
  const state = STATE_WORDS[s.state] ? s.state : "off";
  const wear = num(s.wear_share === null || s.wear_share === undefined ? null
    : 100 * s.wear_share, 0);
  const where = [s.program ? `program ${s.program}` : null, s.line ? `line ${s.line}` : null,
    s.part >= 0 ? `part ${s.part}` : null].filter(Boolean);
  const alarm = state === "alarm";
  const lim = num(s.wear_limit_mm, 3);
  const at = num(s.wear_alarm_share === null || s.wear_alarm_share === undefined ? null
    : 100 * s.wear_alarm_share, 0);
  const apart = Boolean(s.wear_of);
  return {
    state,
    label: STATE_WORDS[state],
    tool: toolText(s.tool),
    // the wear group: whose tool (a title when it is not the spindle's), its number
    wearOf: apart ? `tool wear · ${s.wear_of}` : "tool wear",
    wearApart: apart,
    // a machine with no wear model (no tool, no share, no life): the wear tiles hidden
    wearKnown: Boolean(s.wear_tool) || num(s.wear_share, 3) !== null
      || num(s.life_left_min, 1) !== null,
    wearTool: apart ? toolText(s.wear_tool, false) : toolText(s.wear_tool || s.tool),
    wear: wear === null ? dash : `${wear} %`,
    wearLimit: (lim === null ? "" : `of ${lim} mm` + (at === null ? "" : ` · alarm at ${at} %`))
      + wearInterval(s),
    // the bar: share of the limit, 0..1 (a worn-out tool fills it)
    wearBar: s.wear_share === null || s.wear_share === undefined ? 0
      : Math.max(0, Math.min(1, Number(s.wear_share))),
    life: num(s.life_left_min, 1) === null ? dash : `${num(s.life_left_min, 1)} min`,
    where: where.length ? where.join(" · ") : dash,
    unacked: s.unacked || 0,
    unackedText: s.unacked ? `${s.unacked} to acknowledge` : "nothing to acknowledge",
    // the detector's own sentence names the kind, tool and block; else the kind in words
    message: alarm && latest ? latest.message || KIND_WORDS[latest.kind] || latest.kind : "",
  };
}

// The wear share's 95 % interval and whether its map is this machine's own (issue 35
// item 7: "uncalibrated" until a VB measured at a tool change is entered), or "".
function wearInterval(s) {
  const lo = num(s.wear_lo_share === null || s.wear_lo_share === undefined ? null
    : 100 * s.wear_lo_share, 0);
  const hi = num(s.wear_hi_share === null || s.wear_hi_share === undefined ? null
    : 100 * s.wear_hi_share, 0);
  const cal = s.wear_calibrated === false ? "uncalibrated" : s.wear_calibrated ? "calibrated"
    : "";
  const band = lo === null || hi === null ? "" : `95 %: ${lo}–${hi} %`;
  const words = [cal, band].filter(Boolean).join(", ");
  return words ? ` · ${words}` : "";
}

// Take one event (an EventMessage's event, a REST item) into `events` (a Map id -> event):
// an acknowledgement replaces the raised copy; an older copy never undoes an
// acknowledgement. Returns true when the map changed.
export function mergeEvent(events, ev, keep = 200) {
  const old = events.get(ev.id);
  if (old && old.acked && !ev.acked) return false;
  if (old && JSON.stringify(old) === JSON.stringify(ev)) return false;
  events.set(ev.id, ev);
  if (events.size > keep) {
    const oldest = [...events.values()].sort((a, b) => a.t - b.t).slice(0, events.size - keep);
    for (const e of oldest) events.delete(e.id);
  }
  return true;
}

// Newest first (by simulated time; a reset starts time again, so ties go by id).
export function ordered(events) {
  return [...events.values()].sort((a, b) => b.t - a.t || (a.id < b.id ? 1 : -1));
}

// Does this event wait for an operator? (every unacknowledged feed hold or alarm)
export function waiting(ev) {
  return !ev.acked && ev.action !== "notice";
}

// The event the strip names while in alarm: the newest waiting feed hold (the machine
// stopped for it), else the newest waiting alarm; null when none waits.
export function headline(events) {
  const w = ordered(events).filter(waiting);
  return w.find((e) => e.action === "feed_hold") || w[0] || null;
}

// the limit an event crossed, in words where a bare number would read as another limit
// (the wear alarm's threshold is a share of the tool's flank-wear limit, not that limit)
const THRESHOLD_WORDS = { wear_limit: "alarm at ", life_short: "alarm below " };

function valueText(ev) {
  const v = num(ev.value, 3);
  const l = num(ev.limit, 3);
  if (v === null && l === null) return dash;
  const u = ev.unit && ev.unit !== "1" ? ` ${ev.unit}` : "";  // "1": a ratio
  return `${v ?? dash} vs ${THRESHOLD_WORDS[ev.kind] || ""}${l ?? dash}${u}`;
}

function wallText(w) {
  if (w === null || w === undefined) return "";
  return new Date(w * 1000).toISOString().slice(11, 19);
}

// One timeline row's cells, in the order of TIMELINE_HEAD.
export const TIMELINE_HEAD = ["t [s]", "event", "tool", "line", "part", "value vs limit",
  "action", "acknowledged"];
export function eventRow(ev) {
  return {
    id: ev.id,
    waiting: waiting(ev),
    kind: ev.kind,
    cells: [
      Number(ev.t).toFixed(3),
      KIND_WORDS[ev.kind] || ev.kind,
      toolText(ev.tool, Boolean(ev.program)),
      ev.line ? String(ev.line) : dash,
      ev.part >= 0 ? String(ev.part) : dash,
      valueText(ev),
      ACTION_WORDS[ev.action] || ev.action,
      ev.acked ? `yes${ev.acked_by ? `, ${ev.acked_by}` : ""}` +
        `${ev.acked_wall ? ` ${wallText(ev.acked_wall)} UTC` : ""}` : "no",
    ],
    message: ev.message,
  };
}

// Why an Acknowledge button is disabled ("" when it is not): the operator's role only.
export function ackRefusal(role) {
  if (role === "operator") return "";
  if (role === "viewer") return "acknowledging needs the operator role (signed in as viewer)";
  return "acknowledging needs the operator role (not signed in)";
}

// The markers in the x range [t0, t1]: [{t, color}], oldest first.
export function markersIn(events, t0, t1) {
  return [...events.values()].filter((e) => e.t >= t0 && e.t <= t1)
    .sort((a, b) => a.t - b.t)
    .map((e) => ({ t: e.t, id: e.id, color: waiting(e) ? MARKER_ALARM : MARKER_DONE }));
}
