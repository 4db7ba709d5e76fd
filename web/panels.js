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
