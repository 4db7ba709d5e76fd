// The dashboard's charts from the stream's own description (no DOM): the hello announces
// the charts (id, title, page, order, window, wide, markers) and every channel with the
// chart it is drawn on, its order there, its colour, axis, dash, width, its interval band
// or shaded area. chartSpecs() turns that into uPlot series; app.js draws what it returns.
// No channel's name is written here (or anywhere in web/): a new estimate on the live view
// is a part on the server. tests/service/test_protocol.py runs this under node.

export const BAND_FILL = "rgba(0, 158, 115, 0.18)";
const FILL = "rgba(0, 158, 115, 0.15)";
const GREY = "#9aa0a6";
// colours for channels that name none
export const PALETTE = ["#0072b2", "#e69f00", "#009e73", "#cc3311", "#56b4e9", "#7b3294",
  "#888888"];
// the pages, in the order they are shown
export const PAGES = ["operator", "research"];

// A channel's legend label: its short legend, else its label and its unit in brackets.
export function legendLabel(c) {
  if (c.legend) return c.legend;
  return c.unit ? `${c.label} [${c.unit}]` : c.label;
}

// An identified parameter with its 95 % interval (c.interval: lower, upper, excited
// channels), as chart series [channel, label, color, scale, opts] and the band between the
// bounds: the estimate where excited; greyed, dashed and labelled "not excited" (no number)
// where not; the bounds, shaded, where excited. `first` is the uPlot index of its first
// series. null when the stream lacks one of the interval's channels (names: a Set).
export function intervalSeries(c, names, first) {
  const iv = c.interval;
  if (!iv || ![iv.lower, iv.upper, iv.excited].every((n) => names.has(n))) return null;
  const ex = iv.excited;
  const color = c.color || PALETTE[2];
  return {
    series: [
      [c.name, `${c.legend || c.label}, 95 % band`, color, undefined,
        { mask: [ex, 1], width: c.width }],
      [c.name, "not excited", GREY, undefined,
        { mask: [ex, 0], dash: [6, 4], width: c.width, notExcited: true }],
      [iv.upper, "95 % upper", color, undefined, { mask: [ex, 1], width: 0.5 }],
      [iv.lower, "95 % lower", color, undefined, { mask: [ex, 1], width: 0.5 }],
    ],
    bands: [{ series: [first + 2, first + 3], fill: BAND_FILL }],
    excited: ex,
  };
}

// One chart's spec from its channels (sorted by their order): series
// [channel, label, color, scale, opts], uPlot bands, the excited flag's channel (null:
// none), the second axis' scale (null: none).
function chartSpec(chart, channels, names) {
  const series = [];
  const bands = [];
  let excited = null;
  const index = {};
  channels.forEach((c, i) => {
    const iv = intervalSeries(c, names, 1 + series.length);
    if (iv) {
      series.push(...iv.series);
      bands.push(...iv.bands);
      excited = excited || iv.excited;
      return;
    }
    index[c.name] = 1 + series.length;
    series.push([c.name, legendLabel(c), c.color || PALETTE[i % PALETTE.length],
      c.axis || undefined, { width: c.width, ...(c.dash && c.dash.length ? { dash: c.dash } : {}) }]);
  });
  for (const c of channels) {
    if (c.fill_to && index[c.name] && index[c.fill_to]) {
      bands.push({ series: [index[c.name], index[c.fill_to]], fill: FILL });
    }
  }
  const axis = series.find((s) => s[3]);
  return { ...chart, series, bands, excited, scale: axis ? axis[3] : null };
}

// The charts of a hello (its charts and channels), by page then order: each with its
// series, bands, excited flag and second axis. A chart none of whose channels is
// announced is left out.
export function chartSpecs(hello) {
  const names = new Set(hello.channels.map((c) => c.name));
  const byChart = {};
  for (const c of hello.channels) {
    if (!c.chart) continue;
    (byChart[c.chart] = byChart[c.chart] || []).push(c);
  }
  return hello.charts
    .filter((ch) => byChart[ch.id])
    .map((ch) => chartSpec(ch, byChart[ch.id].sort((a, b) => a.order - b.order), names))
    .sort((a, b) => PAGES.indexOf(a.page) - PAGES.indexOf(b.page) || a.order - b.order);
}

// The channel of each role the residual loop's panel compares (reference, without_effects,
// with_effects): role -> channel name.
export function roles(channels) {
  return Object.fromEntries(channels.filter((c) => c.role).map((c) => [c.role, c.name]));
}

// The force estimates' labels and colours (the accuracy panel): name -> [label, color].
export function forceLooks(channels) {
  return Object.fromEntries(channels.filter((c) => c.group === "force" && !c.truth)
    .map((c) => [c.name, [c.legend || c.label, c.color]]));
}
