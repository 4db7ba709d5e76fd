"""The residual report (docs/design.md): ``report.json``, ``estimates.csv``, ``report.html``.

All three files are rendered in memory, written to a temporary directory beside the
output directory and moved into place only when complete, so a failure leaves no
partial output behind.
"""

from __future__ import annotations

import base64
import html
import io
import json
import os
import shutil
import tempfile
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from common.jsonsafe import json_safe
from estimators.residual.engine import ResidualResult
from estimators.residual.families import FAMILIES as RIGID_FAMILIES
from server.records.measured_log import MeasuredLog


def describe_structure(u: Mapping[str, Any]) -> str:
    """One line for an ``unexplained`` entry, e.g. ``time: 23.7 Hz, 0.047``."""
    amp = u.get("amplitude")
    amp_s = f"{amp:.3g}" if isinstance(amp, int | float) else "?"
    if "frequency_hz" in u:
        return f"{u.get('domain', 'time')}: {u['frequency_hz']:.4g} Hz, amplitude {amp_s}"
    if "period" in u:
        return f"{u.get('domain', 'position')}: period {u['period']:.4g}, amplitude {amp_s}"
    return ", ".join(f"{k}={v}" for k, v in u.items())


#: the physical meaning of each family, shown beside its parameters
MEANING: dict[str, str] = {
    "none": "nothing beyond the nominal model",
    "torque_ripple": "motor torque periodic in the motor angle",
    "backlash": "lost motion between motor and load at reversals",
    **{name: fam.meaning for name, fam in RIGID_FAMILIES.items()},
}


def selection_text(res: ResidualResult) -> str:
    """The decision rule, in one sentence with its numbers (docs/residual-selection.md)."""
    sp = res.selection
    return (
        f"greedy; per round, blocked {sp.folds}-fold cross-validation over the fitting "
        "part (contiguous folds, guard gaps of the filters' memory, shapes searched again "
        "inside each training fold); effect = out-of-fold mean-square reduction on the "
        f"candidate's support (rows where its term is >= {sp.support_level:g} of its "
        "99th percentile) relative to the floor (out-of-fold mean square over all "
        f"fitting rows); one-sided t-test over {sp.blocks} groups of support rows, "
        f"Holm-corrected over the round's candidates at {sp.alpha:g}; accepted when it "
        f"passes and the effect is >= {sp.min_effect:g}; the largest out-of-fold "
        "reduction is added; candidates whose terms correlate >= "
        f"{sp.same_signal:g} with it and remove within {sp.tie:.0%} as much are named "
        "indistinguishable (the one with fewer columns is installed)"
    )


def report_dict(
    log: MeasuredLog,
    res: ResidualResult,
    validation: Mapping[str, Any] | None = None,
    notes: Sequence[str] = (),
) -> dict[str, Any]:
    """The ``report.json`` object (the design's contract keys plus details; ``notes``: what
    the rate, the rows used and the unit mean for this record)."""
    rep: dict[str, Any] = {
        "log": str(log.path),
        "model": res.model,
        "kind": res.kind,
        "n_samples": log.n,
        "rows": {
            "read": log.n_read or log.n,
            "used": log.n,
            "left_out": list(log.left_out),
            "pieces": len(log.segments),
        },
        "sample_time": log.sample_time,
        "holdout": {"start": res.holdout_start, "stop": res.holdout_stop},
        "rms_before": res.rms_before,
        "rms_after": res.rms_after,
        "relerr_before": res.relerr_before,
        "relerr_after": res.relerr_after,
        "selected": [e.name for e in res.effects],
        "candidates": [
            {
                "name": c.name,
                "params": c.params,
                "rms_before": c.rms_before,
                "rms_after": c.rms_after,
                "score": c.score,
                "t_stat": c.t_stat,
                "selected": c.selected,
                "note": c.note,
                "meaning": MEANING.get(c.name, ""),
                "cv_effect": c.cv_effect,
                "p_value": c.p_value,
                "passed": c.passed,
                "support_fraction": c.support_fraction,
                "blocks_tested": c.folds_used,
            }
            for c in res.candidates
        ],
        # the selected effects in order, each with its physical meaning, parameters and
        # shape (what a live model loads: cutwatch serve --model REPORT.json)
        "effects": [
            {
                "name": c.name,
                "meaning": MEANING.get(c.name, ""),
                "params": c.params,
                "shape": dict(e.shape),
            }
            for e in res.effects
            for c in res.candidates
            if c.name == e.name
        ],
        "unexplained": list(res.unexplained),
        # canonical families this kind does not offer, and why
        "not_offered": dict(res.not_offered),
        "parameters_before": dict(zip(res.names_before, map(float, res.theta_before))),
        "parameters_after": dict(zip(res.names_after, map(float, res.theta_after))),
        "units": log.units,
        "indistinguishable": [dict(a) for a in res.indistinguishable],
        "selection_test": selection_text(res),
        "score": "relative reduction of the held-out mean square error (1 - mse_after/"
        "mse_before) at the round the candidate was last scored (report figure only: the "
        "held-out end takes no part in the selection)",
    }
    # the model's own entries (the observer: per-channel figures and its terms)
    rep.update(res.details)
    if notes:
        rep["notes"] = list(notes)
    if validation is not None:
        rep["validation"] = dict(validation)
    return json_safe(rep)


def live_effects(report: Mapping[str, Any], source: str = "report") -> list[Any]:
    """The effects a residual report selected, as the live rigid model loads them
    (:class:`estimators.rigid_id.LiveEffect`: family and shape; the coefficients are
    identified live). A report written before the ``shape`` key: the shape is its
    ``params`` less the family's coefficients and derived figures.

    Raises
    ------
    server.errors.LogFormatError
        Not a rigid residual report, or an effect of an unknown family (named).
    """
    from estimators.rigid_id import LiveEffect
    from server.errors import LogFormatError

    effects = report.get("effects") if isinstance(report, Mapping) else None
    if not isinstance(effects, list) or report.get("kind", "rigid") != "rigid":
        raise LogFormatError(
            f"{source}: expected a rigid residual report (report.json with 'effects'), "
            f"found kind {report.get('kind') if isinstance(report, Mapping) else report!r}"
        )
    out = []
    zero = {"M": 0.0, "Fv": 0.0, "Fc": 0.0, "offset": 0.0}
    for i, e in enumerate(effects):
        name = e.get("name") if isinstance(e, Mapping) else None
        fam = RIGID_FAMILIES.get(name) if isinstance(name, str) else None
        params = e.get("params", {}) if isinstance(e, Mapping) else {}
        if fam is None or not isinstance(params, Mapping):
            raise LogFormatError(
                f"{source}: effects[{i}]: expected a family of {sorted(RIGID_FAMILIES)}, "
                f"found {name!r}"
            )
        shape = e.get("shape")
        if not isinstance(shape, Mapping):  # an older report: params less coefficients
            drop = set(fam.column_names(params)) | set(fam.derived(params, params, zero))
            shape = {k: v for k, v in params.items() if k not in drop}
        out.append(LiveEffect.of(str(name), {k: float(v) for k, v in shape.items()}))
    return out


def _png(fig: Any) -> str:
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=90, bbox_inches="tight")
    return base64.b64encode(buf.getvalue()).decode("ascii")


def _position_spectrum(q: np.ndarray, r: np.ndarray, periods: np.ndarray) -> np.ndarray:
    """Amplitude of the best-fitting sinusoid in position at each period (least squares)."""
    stride = max(1, len(q) // 20_000)  # a display: 20,000 points are plenty
    q, r = q[::stride], r[::stride]
    amp = np.empty(len(periods))
    rr = r - r.mean()
    for i, p in enumerate(periods):
        w = 2.0 * np.pi * q / p
        a = np.column_stack([np.cos(w), np.sin(w)])
        coef, *_ = np.linalg.lstsq(a, rr, rcond=None)
        amp[i] = float(np.hypot(coef[0], coef[1]))
    return amp


#: what each family's shape is drawn against (velocity: the friction curve with the
#: nominal friction; position: per direction; time; acceleration)
SHAPE_AXIS: dict[str, str] = {
    "viscous": "velocity",
    "coulomb_asymmetry": "velocity",
    "stribeck": "velocity",
    "friction_curve": "velocity",
    "viscous_asymmetry": "velocity",
    "load": "velocity",
    "position_friction": "position",
    "position_periodic": "position",
    "position_harmonics": "position",
    "torque_ripple": "position",
    "backlash": "position",
    "harmonic": "time",
    "drift": "time",
    "delay": "time",
    "drive_delay": "time",
    "force_lag": "time",
    "offset": "time",
    "inertia": "acceleration",
}


def _plt() -> Any:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def _verdict_figure(res: ResidualResult, unit: str) -> tuple[str, str]:
    """Held-out error before and after (bars), and the held-out residual against time."""
    plt = _plt()
    fig, (ax0, ax1) = plt.subplots(1, 2, figsize=(10, 3), gridspec_kw={"width_ratios": [1, 3]})
    vals = [res.relerr_before, res.relerr_after]
    bars = ax0.bar(["nominal", "with effects"], vals, color=["0.6", "tab:green"])
    for bar, v in zip(bars, vals):
        ax0.annotate(f"{v:.3g} %", (bar.get_x() + bar.get_width() / 2, v), ha="center",
                     va="bottom")  # fmt: skip
    ax0.set_ylabel("held-out relative error [%]")
    ax0.set_ylim(0, max(vals) * 1.2 + 1e-12)
    hold = res.t_dec >= res.holdout_start
    ax1.plot(res.t_dec[hold], res.residual_before_dec[hold], ".", ms=2, color="0.5",
             label="nominal")  # fmt: skip
    ax1.plot(res.t_dec[hold], res.residual_after_dec[hold], ".", ms=2, color="tab:green",
             label="with effects")  # fmt: skip
    ax1.set_xlabel("t [s] (held-out end)")
    ax1.set_ylabel(f"error [{unit}]")
    ax1.legend(loc="upper right")
    fig.tight_layout()
    out = ("Held-out error, before and after", _png(fig))
    plt.close(fig)
    return out


def _nominal_friction(res: ResidualResult, qd: np.ndarray) -> np.ndarray:
    """Fv*qd + Fc*sign(qd) of the final model, where the model has those parameters."""
    th = dict(zip(res.names_after, map(float, res.theta_after)))
    return th.get("Fv", 0.0) * qd + th.get("Fc", 0.0) * np.sign(qd)


def _shape_figures(res: ResidualResult, unit: str, pos_unit: str) -> list[tuple[str, str]]:
    """Each selected effect drawn as its shape (needs the result's per-effect terms)."""
    terms: Mapping[str, np.ndarray] | None = getattr(res, "terms_dec", None)
    if not terms:
        return []
    plt = _plt()
    out: list[tuple[str, str]] = []
    qd, q, t = res.qd_dec, res.q_dec, res.t_dec
    qdd = getattr(res, "qdd_dec", None)
    shapes = {e.name: dict(e.shape) for e in res.effects}
    for name, term in terms.items():
        axis = SHAPE_AXIS.get(name, "time")
        fig, ax = plt.subplots(figsize=(9, 3))
        if axis == "velocity":
            order = np.argsort(qd)
            base = _nominal_friction(res, qd)
            ax.plot(qd[order], base[order], lw=1, color="0.5", label="nominal friction")
            ax.plot(qd[order], (base + term)[order], ".", ms=2, color="tab:red",
                    label=f"with {name}")  # fmt: skip
            ax.set_xlabel(f"velocity [{pos_unit}/s]")
            title = f"{name}: friction against velocity"
        elif axis == "position":
            period = shapes.get(name, {}).get("period", 0.0)
            window = np.ones(len(q), dtype=bool)
            if period > 0 and np.ptp(q) > 5 * period:  # four periods mid-travel
                q0 = float(np.median(q))
                window = (q >= q0) & (q <= q0 + 4 * period)
            for sel, lab, col in ((qd > 0, "v > 0", "tab:blue"), (qd < 0, "v < 0", "tab:orange")):
                sel = sel & window
                order = np.argsort(q[sel])
                ax.plot(q[sel][order], term[sel][order], lw=1, color=col, label=lab)
            ax.set_xlabel(f"position [{pos_unit}]")
            title = f"{name}: against position, per direction" + (
                f" (four periods of {period:.4g} {pos_unit})" if not window.all() else ""
            )
        elif axis == "acceleration" and qdd is not None:
            ax.plot(qdd, term, ".", ms=2, color="tab:red", label=name)
            ax.set_xlabel(f"acceleration [{pos_unit}/s²]")
            title = f"{name}: against acceleration"
        else:
            ax.plot(t, term, lw=0.8, color="tab:red", label=name)
            ax.set_xlabel("t [s]")
            title = f"{name}: against time"
        ax.set_ylabel(f"effort [{unit}]")
        ax.axhline(0.0, color="0.8", lw=0.5)
        ax.legend(loc="upper right")
        out.append((title, _png(fig)))
        plt.close(fig)
    return out


def _figures(res: ResidualResult, unit: str, pos_unit: str = "") -> list[tuple[str, str]]:
    """The detail figures: residual against time, velocity, position; its spectra."""
    plt = _plt()
    r0, r1 = res.residual_before_dec, res.residual_after_dec
    out: list[tuple[str, str]] = []
    fig, ax = plt.subplots(figsize=(9, 3))
    ax.plot(res.t_dec, r0, lw=0.6, label="before")
    ax.plot(res.t_dec, r1, lw=0.6, label="after")
    ax.axvspan(res.holdout_start, res.holdout_stop, color="0.9", label="held out")
    ax.set_xlabel("t [s]")
    ax.set_ylabel(f"residual [{unit}]")
    ax.legend(loc="upper right")
    out.append(("Residual against time", _png(fig)))
    plt.close(fig)
    for xs, lab, title in (
        (res.qd_dec, f"velocity [{pos_unit}/s]", "Residual against velocity"),
        (res.q_dec, f"position [{pos_unit}]", "Residual against position"),
    ):
        fig, ax = plt.subplots(figsize=(9, 3))
        ax.plot(xs, r0, ".", ms=1.5, label="before")
        ax.plot(xs, r1, ".", ms=1.5, label="after")
        ax.set_xlabel(lab)
        ax.set_ylabel(f"residual [{unit}]")
        ax.legend(loc="upper right")
        out.append((title, _png(fig)))
        plt.close(fig)
    fig, ax = plt.subplots(figsize=(9, 3))
    dt = float(np.median(np.diff(res.t_dec)))
    for r, lab in ((r0, "before"), (r1, "after")):
        win = np.hanning(len(r))
        spec = np.abs(np.fft.rfft((r - r.mean()) * win)) * 2.0 / win.sum()
        ax.semilogy(np.fft.rfftfreq(len(r), dt)[1:], spec[1:] + 1e-300, lw=0.6, label=lab)
    ax.set_xlabel("frequency [Hz]")
    ax.set_ylabel(f"amplitude [{unit}]")
    ax.legend(loc="upper right")
    out.append(("Residual spectrum (time)", _png(fig)))
    plt.close(fig)
    span = float(np.ptp(res.q_dec))
    if span > 0:
        periods = np.geomspace(span * 1e-3, span / 2.0, 200)
        fig, ax = plt.subplots(figsize=(9, 3))
        for r, lab in ((r0, "before"), (r1, "after")):
            ax.loglog(
                periods, _position_spectrum(res.q_dec, r, periods) + 1e-300, lw=0.8, label=lab
            )
        ax.set_xlabel(f"period in position [{pos_unit}]")
        ax.set_ylabel(f"amplitude [{unit}]")
        ax.legend(loc="upper right")
        out.append(("Residual spectrum (position)", _png(fig)))
        plt.close(fig)
    return out


def _fmt(x: Any) -> str:
    if isinstance(x, float):
        return f"{x:.5g}"
    return html.escape(str(x))


def _img(title: str, b64: str) -> str:
    t = html.escape(title)
    return (
        f"<figure><img alt='{t}' src='data:image/png;base64,{b64}'>"
        f"<figcaption>{t}</figcaption></figure>"
    )


def verdict_text(rep: Mapping[str, Any]) -> str:
    """One sentence: what the log's nominal model missed and what adding it gained."""
    b, a = rep["relerr_before"], rep["relerr_after"]
    sel = rep["selected"]
    gain = 100.0 * (1.0 - a / b) if b > 0 else 0.0
    if not sel:
        return (
            f"Nothing added: no effect passed the selection; the nominal model's held-out "
            f"error is {b:.3g} %."
        )
    return (
        f"Found {len(sel)} effect{'s' if len(sel) > 1 else ''} ({', '.join(sel)}): the held-out "
        f"error falls from {b:.3g} % to {a:.3g} % ({gain:.0f} % lower)."
    )


def report_html(
    rep: Mapping[str, Any],
    figures: list[tuple[str, str]],
    lead: list[tuple[str, str]] | None = None,
) -> str:
    """A self-contained page: the verdict and the figures first (error before and after,
    each selected effect drawn as its shape), then the details folded (raw coefficients,
    candidates, residual figures). PNG figures are inlined as base64."""
    rows = "".join(
        f"<tr><td>{_fmt(c['name'])}</td><td>{'yes' if c['selected'] else ''}</td>"
        f"<td>{_fmt(c['cv_effect'])}</td><td>{_fmt(c['p_value'])}</td>"
        f"<td>{'yes' if c['passed'] else ''}</td>"
        f"<td>{_fmt(c['score'])}</td><td>{_fmt(c['t_stat'])}</td>"
        f"<td>{_fmt(c['rms_before'])}</td><td>{_fmt(c['rms_after'])}</td>"
        f"<td>{_fmt(', '.join(f'{k}={_fmt(v)}' for k, v in c['params'].items()))}</td>"
        f"<td>{_fmt(c['note'])}</td></tr>"
        for c in rep["candidates"]
    )
    params = "".join(
        f"<tr><td>{_fmt(k)}</td><td>{_fmt(v)}</td><td>"
        f"{_fmt(rep['parameters_after'].get(k, ''))}</td></tr>"
        for k, v in rep["parameters_before"].items()
    )
    params += "".join(
        f"<tr><td>{_fmt(k)}</td><td></td><td>{_fmt(v)}</td></tr>"
        for k, v in rep["parameters_after"].items()
        if k not in rep["parameters_before"]
    )
    effects = "".join(
        f"<li><b>{_fmt(e['name'])}</b>: {_fmt(e['meaning'])}</li>" for e in rep.get("effects", [])
    )
    coefs = "".join(
        f"<tr><td>{_fmt(e['name'])}</td>"
        f"<td>{_fmt(', '.join(f'{k}={_fmt(v)}' for k, v in e['params'].items()))}</td></tr>"
        for e in rep.get("effects", [])
    )
    unexpl = (
        "".join(f"<li>{_fmt(describe_structure(u))}</li>" for u in rep["unexplained"])
        or "<li>no structure above the reporting threshold</li>"
    )
    not_off = "".join(
        f"<li>not offered: {_fmt(k)} — {_fmt(v)}</li>" for k, v in rep["not_offered"].items()
    )
    val = ""
    if "validation" in rep:
        v = rep["validation"]
        val = (
            f"<p><b>On a second record</b> ({_fmt(v['log'])}): relative error "
            f"{_fmt(v['relerr_before'])} % → {_fmt(v['relerr_after'])} % (rms "
            f"{_fmt(v['rms_before'])} → {_fmt(v['rms_after'])}).</p>"
        )
    ambig = "".join(
        f"<p><b>Indistinguishable on this record: {_fmt(' and '.join(a['families']))}</b> "
        f"({_fmt(a['installed'])} installed). {_fmt(a['why'])}. To tell them apart: "
        f"{_fmt(a['excitation'])}.</p>"
        for a in rep.get("indistinguishable", [])
    )
    rows_used = ""
    r = rep.get("rows")
    if r and r.get("left_out"):
        counts = "; ".join(f"{_fmt(d['left_out'])} by {_fmt(d['rule'])}" for d in r["left_out"])
        rows_used = (
            f"<p>Rows: {_fmt(r['read'])} read, {_fmt(r['used'])} used in "
            f"{_fmt(r['pieces'])} piece(s); left out: {counts}.</p>"
        )
    notes = "".join(f"<p>{_fmt(n)}</p>" for n in rep.get("notes", []))
    lead_figs = "".join(_img(t, b) for t, b in (lead or []))
    figs = "".join(_img(t, b) for t, b in figures)
    unit = rep.get("units", {}).get("effort", "")
    return f"""<!doctype html>
<html lang="en"><head><meta charset="utf-8"><title>cutwatch residual report</title>
<style>body{{font-family:sans-serif;max-width:1000px;margin:auto}}
table{{border-collapse:collapse}}td,th{{border:1px solid #ccc;padding:2px 6px}}
.verdict{{font-size:1.3em;background:#eef6ee;padding:8px;border-left:5px solid #3a3}}
figure{{margin:8px 0}}img{{max-width:100%}}summary{{font-weight:bold;cursor:pointer}}</style>
</head><body>
<h1>Residual report: {_fmt(rep["log"])}</h1>
<p class="verdict">{_fmt(verdict_text(rep))}</p>
<p>Held-out rms {_fmt(rep["rms_before"])} → {_fmt(rep["rms_after"])} {_fmt(unit)}
(t = {_fmt(rep["holdout"]["start"])} … {_fmt(rep["holdout"]["stop"])} s, not used
in the fit). Model: {_fmt(rep["model"])}.</p>
{rows_used}{notes}
<h2>Selected effects and their physical meaning</h2><ul>{effects or "<li>none</li>"}</ul>
{lead_figs}
{ambig}
<h2>What is left unexplained</h2><ul>{unexpl}</ul>
{val}
<details><summary>Raw coefficients (parameters before and after, each effect's
coefficients)</summary>
<table><tr><th>effect</th><th>shape and coefficients</th></tr>{coefs}</table>
<table><tr><th>name</th><th>before</th><th>after</th></tr>{params}</table></details>
<details><summary>Candidates and the selection rule</summary>
<p>Selection: {_fmt(rep["selection_test"])}.</p>
<table><tr><th>name</th><th>selected</th><th>CV effect</th>
<th>p</th><th>passed</th><th>held-out score</th><th>t</th>
<th>rms before</th><th>rms after</th><th>parameters</th><th>note</th></tr>{rows}</table>
<ul>{not_off}</ul></details>
<details><summary>Residual figures (time, velocity, position, spectra)</summary>
{figs}</details>
</body></html>
"""


def write_report(
    out_dir: Path,
    log: MeasuredLog,
    res: ResidualResult,
    validation: Mapping[str, Any] | None = None,
    notes: Sequence[str] = (),
) -> dict[str, Any]:
    """Write ``report.json``, ``estimates.csv`` and ``report.html`` into ``out_dir``."""
    rep = report_dict(log, res, validation, notes)
    unit, pos_unit = log.units.get("effort", ""), log.units.get("position", "")
    lead = [_verdict_figure(res, unit), *_shape_figures(res, unit, pos_unit)]
    figs = _figures(res, unit, pos_unit)
    page = report_html(rep, figs, lead)
    est = io.StringIO()
    np.savetxt(
        est,
        np.column_stack([log["t"], res.f_hat_before, res.f_hat_after]),
        delimiter=",",
        fmt="%.10g",
        header="t,f_hat_before,f_hat_after",
        comments="",
    )
    out = Path(out_dir)
    parent = out.parent
    parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=f".{out.name}.", dir=parent))
    try:
        (tmp / "report.json").write_text(json.dumps(rep, indent=2) + "\n")
        (tmp / "estimates.csv").write_text(est.getvalue())
        (tmp / "report.html").write_text(page)
        out.mkdir(exist_ok=True)
        for name in ("estimates.csv", "report.html", "report.json"):
            os.replace(tmp / name, out / name)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    return rep
