// Pure helpers of the dashboard's panels (no DOM): the interval bands of the identified
// parameters and the accuracy panel's title and table. tests/service/test_protocol.py
// runs them under node; app.js draws what they return.
import { SCHEMA } from "./protocol.js";

export const BAND_FILL = "rgba(0, 158, 115, 0.18)";
const BAND = "#009e73";
const GREY = "#9aa0a6";

// An identified parameter with its 95 % interval (SCHEMA.intervals[q]: estimate, lower,
// upper, excited channels), as chart series [channel, label, color, scale, opts] and the
// band between the bounds: the estimate where excited; greyed, dashed and labelled "not
// excited" (no number) where not; the bounds, shaded, where excited. `first` is the uPlot
// index of the first added series (1 + the chart's other series). null when the stream
// lacks any of the four channels (names: the hello's channel names).
export function intervalSeries(q, names, first, intervals = SCHEMA.intervals || {}) {
  const iv = intervals[q];
  if (!iv || ![iv.estimate, iv.lower, iv.upper, iv.excited].every((n) => names.has(n))) return null;
  const ex = iv.excited;
  return {
    series: [
      [iv.estimate, "identified, 95 % band", BAND, undefined, { mask: [ex, 1], width: 2 }],
      [iv.estimate, "not excited", GREY, undefined,
        { mask: [ex, 0], dash: [6, 4], width: 2, notExcited: true }],
      [iv.upper, "95 % upper", BAND, undefined, { mask: [ex, 1], width: 0.5 }],
      [iv.lower, "95 % lower", BAND, undefined, { mask: [ex, 1], width: 0.5 }],
    ],
    bands: [{ series: [first + 2, first + 3], fill: BAND_FILL }],
    excited: ex,
  };
}

const WORDS = {
  truth: "Force accuracy: rms error of each estimate against the truth, and against " +
    "Q(s)·truth (what an observer with this Q can reach)",
  agreement: "Force estimates' agreement (no truth in this source): rms of each estimate " +
    "minus the mean of the estimates",
};

// The panel's title for an accuracy object (SCHEMA.accuracy).
export function accuracyTitle(acc) {
  return `${WORDS[acc.mode]}, last ${acc.windows.map((x) => `${x} s`).join(" / ")}`;
}

function num(v) {
  return v == null ? "–" : Number(v).toPrecision(3);
}

// {head: [column titles], rows: [{key, label, cells: [text]}]} of the accuracy table.
// labels: channel name -> display label.
export function accuracyTable(acc, labels = {}) {
  // a window not yet full says how much it covers
  const wins = acc.windows.map((x, i) => (acc.span[i] < x - 1e-6
    ? `${x} s (${acc.span[i].toFixed(1)} s so far)` : `${x} s`));
  const truth = acc.mode === "truth";
  const head = ["estimate", ...wins.map((w) => (truth ? `vs truth, ${w}` : `vs mean, ${w}`))];
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
