"""Write the wear report: DIR/estimates.csv, DIR/report.json, DIR/report.html.

The page leads with the verdict (our error beside the baselines') and the figures (VB
measured against estimated with its 95 % band, per tool, on the segment index: the
table has no cutting time); the numbers follow, folded.
"""

from __future__ import annotations

import base64
import csv
import html
import io
import json
import math
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from common.arrays import F64
from common.jsonsafe import json_safe

ESTIMATE_COLUMNS = (
    "tool", "segment", "vb_true", "vb_est", "vb_lo", "vb_hi",
    "life_left", "life_left_lo", "life_left_hi",
)  # fmt: skip


def write_estimates(path: Path, rows: Sequence[Mapping[str, float]], has_vb: bool) -> None:
    """One row per segment; ``vb_true`` only when the table has it."""
    cols = [c for c in ESTIMATE_COLUMNS if has_vb or c != "vb_true"]
    with path.open("w", newline="") as f:
        w = csv.writer(f)
        w.writerow(cols)
        for r in rows:
            w.writerow([_cell(r[c]) for c in cols])


def _cell(x: Any) -> str:
    if isinstance(x, int | np.integer):
        return str(int(x))
    v = float(x)
    return "inf" if math.isinf(v) else f"{v:.6g}"


def _png(fig: Any) -> str:
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=80, bbox_inches="tight")
    return base64.b64encode(buf.getvalue()).decode("ascii")


def tool_figure(
    tool: int, vb: F64 | None, est: Mapping[str, F64], base: Mapping[str, F64], signal: str
) -> str:
    """PNG (base64) of VB measured vs estimated with its band for one tool."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    k = np.arange(len(est["vb"]))
    fig, ax = plt.subplots(figsize=(5.2, 3.0))
    ax.fill_between(k, est["vb_lo"], est["vb_hi"], color="C0", alpha=0.2, label="95 % band")
    ax.plot(k, est["vb"], color="C0", label=f"estimated ({signal})")
    if vb is not None:
        ax.plot(k, vb, color="k", lw=1.2, label="measured")
    for i, (n, v) in enumerate(base.items()):
        ax.plot(k, v, lw=0.7, ls=":", color=f"C{i + 1}", label=n)
    ax.set_xlabel("segment (no cutting time in the table)")
    ax.set_ylabel("VB [um]")
    ax.set_title(f"tool {tool}")
    ax.legend(fontsize=7, loc="upper left")
    out = _png(fig)
    plt.close(fig)
    return out


def _fmt(x: Any) -> str:
    if isinstance(x, float):
        return "-" if not math.isfinite(x) else f"{x:.3g}"
    return html.escape(str(x))


def verdict(rep: Mapping[str, Any]) -> str:
    """One sentence: our MAE against the baselines, coverage, width."""
    ov = rep.get("overall")
    if not ov:
        return "No measured VB in the table: estimates only, nothing to score."
    parts = [f"MAE {ov['mae']:.1f} um (RMSE {ov['rmse']:.1f})"]
    for n, b in ov.get("baselines", {}).items():
        parts.append(
            f"{n} {b['mae']:.1f} um (ours lower on {b['tools_ours_lower']} of "
            f"{len(rep['per_tool'])} tools)"
        )
    parts.append(
        f"95 % band covers {100 * ov['coverage']:.0f} % of segments, median width "
        f"{ov['interval_median_width']:.0f} um"
    )
    if ov.get("life_tools"):
        parts.append(
            "remaining life at half-life: median |error| "
            f"{100 * ov['life_median_abs_rel_error']:.0f} % "
            f"({ov['life_tools']} tools reach {rep['criterion_um']:g} um)"
        )
    return "; ".join(parts) + "."


def _trained(train: Any) -> str:
    if isinstance(train, str):
        return f"Each tool estimated by a model fitted on the others ({train})"
    return f"Trained on tools {', '.join(map(str, train))}"


def report_html(rep: Mapping[str, Any], figures: Sequence[tuple[str, str]]) -> str:
    """Self-contained page: verdict, figures, then the tables folded."""
    head = (
        f"<h1>Flank wear from {html.escape(rep['signal'])} "
        f"({html.escape(rep['column'])})</h1>"
        f"<p class='verdict'><b>{html.escape(verdict(rep))}</b></p>"
        f"<p>{html.escape(_trained(rep['train_tools']))}; life in segments "
        "(the table has no cutting time).</p>"
    )
    figs = "".join(
        f"<figure><img alt='{html.escape(t)}' src='data:image/png;base64,{b}'></figure>"
        for t, b in figures
    )
    cols = ["tool", "segments", "mae", "rmse", "coverage", "interval_median_width",
            "life_error_at_half", "life_error_at_half_150um", "feed_glitches_replaced"]  # fmt: skip
    rows = "".join(
        "<tr>"
        + "".join(f"<td>{_fmt(m.get(c, float('nan')))}</td>" for c in cols)
        + "".join(f"<td>{_fmt(b['mae'])}</td>" for b in m.get("baselines", {}).values())
        + "</tr>"
        for m in rep["per_tool"]
    )
    bnames = list(rep["per_tool"][0].get("baselines", {})) if rep["per_tool"] else []
    th = "".join(f"<th>{c}</th>" for c in cols + [f"{n} mae" for n in bnames])
    model = html.escape(json.dumps(rep.get("model", {}), indent=1))
    return (
        "<!doctype html><meta charset='utf-8'><title>cutwatch wear</title>"
        "<style>body{font-family:sans-serif;max-width:1100px;margin:auto}"
        "figure{display:inline-block;margin:4px}td,th{padding:2px 6px;text-align:right}"
        ".verdict{font-size:1.1em}</style>"
        f"{head}<section class='figures'>{figs}</section>"
        f"<details><summary>per-tool numbers</summary><table><tr>{th}</tr>{rows}</table>"
        "</details>"
        f"<details><summary>fitted model</summary><pre>{model}</pre></details>"
    )


def write_report(
    out: Path,
    rep: Mapping[str, Any],
    rows: Sequence[Mapping[str, float]],
    figures: Sequence[tuple[str, str]],
    has_vb: bool,
) -> None:
    """Write the three files into ``out`` (created)."""
    out.mkdir(parents=True, exist_ok=True)
    write_estimates(out / "estimates.csv", rows, has_vb)
    (out / "report.json").write_text(json.dumps(json_safe(dict(rep)), indent=2) + "\n")
    (out / "report.html").write_text(report_html(rep, figures))


__all__ = ["ESTIMATE_COLUMNS", "report_html", "tool_figure", "verdict", "write_report"]
