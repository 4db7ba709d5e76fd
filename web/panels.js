// Pure helpers of the dashboard's panels (no DOM): the accuracy panel's title and table
// (the charts and their interval bands: charts.js). tests/service/test_protocol.py runs
// them under node; app.js draws what they return.
const WORDS = {
  truth: "Force accuracy: rms error of each estimate against the truth, and against " +
    "Q(s)·truth (what an observer with this Q can reach)",
  measured_force: "Force accuracy: rms error of each estimate against the measured force " +
    "(f_ext)",
};

// The panel's title for an accuracy object (SCHEMA.accuracy): with no reference, the
// reason, and nothing ranked.
export function accuracyTitle(acc) {
  if (acc.mode === "none") return `Force accuracy: ${acc.reason}`;
  return `${WORDS[acc.mode]}, last ${acc.windows.map((x) => `${x} s`).join(" / ")}`;
}

function num(v) {
  return v == null ? "–" : Number(v).toPrecision(3);
}

// {head: [column titles], rows: [{key, label, cells: [text]}]} of the accuracy table.
// labels: channel name -> display label.
export function accuracyTable(acc, labels = {}) {
  if (acc.mode === "none") {  // nothing to score against: the estimates, no numbers
    return { head: ["estimate", "not scored"],
      rows: Object.keys(acc.rms).map((k) => ({ key: k, label: labels[k] || k,
        cells: ["no reference"] })) };
  }
  // a window not yet full says how much it covers
  const wins = acc.windows.map((x, i) => (acc.span[i] < x - 1e-6
    ? `${x} s (${acc.span[i].toFixed(1)} s so far)` : `${x} s`));
  const truth = acc.mode === "truth";
  const vs = truth ? "vs truth" : "vs measured force";
  const head = ["estimate", ...wins.map((w) => `${vs}, ${w}`)];
  if (truth) head.push(...wins.map((w) => `vs Q(s)·truth, ${w}`));
  const rows = Object.keys(acc.rms).map((k) => ({
    key: k,
    label: labels[k] || k,
    cells: [...acc.rms[k].map(num), ...(truth ? (acc.rms_q[k] || []).map(num) : [])],
  }));
  if (truth) {
    rows.push({ key: "q_floor", label: "Q(s)·truth (the Q filter's own error)",
      cells: [...acc.floor.map(num), ...acc.floor.map(() => "0")] });
  }
  return { head, rows };
}

// 4 significant digits; tiny or huge numbers (an inertia ~ 1e-4 kg m^2) in exponent form
function sig(v) {
  const a = Math.abs(v);
  return a !== 0 && (a < 1e-2 || a >= 1e5) ? v.toExponential(3) : String(Number(v.toPrecision(4)));
}

// The identified parameters with their 95 % intervals (issue 31: the machine's page), from
// the hello's channels that carry an interval and the latest finite value of each channel
// seen so far (latest: name -> number). Rows [{key, label, unit, value, interval, excited}]
// in the channels' order, only for parameters estimated at least once (a part that does
// not run streams none). Where the data do not determine it (excited 0) the estimate is
// not given as a number, as on its chart.
export function parameterRows(channels, latest) {
  const rows = [];
  for (const c of channels) {
    const iv = c.interval;
    if (!iv || latest[c.name] == null) continue;
    const ex = latest[iv.excited];
    const excited = ex == null ? null : ex !== 0;
    const lo = latest[iv.lower];
    const hi = latest[iv.upper];
    const shown = excited !== false;
    rows.push({
      key: c.name,
      label: c.label,
      unit: c.unit,
      value: shown ? sig(latest[c.name]) : "not excited",
      interval: shown && lo != null && hi != null ? `[${sig(lo)}, ${sig(hi)}]` : "–",
      excited,
    });
  }
  return rows;
}

// The names parameterRows reads: every channel with an interval and its interval's.
export function parameterChannels(channels) {
  return channels.filter((c) => c.interval)
    .flatMap((c) => [c.name, c.interval.lower, c.interval.upper, c.interval.excited]);
}
