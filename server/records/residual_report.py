"""The residual report of DESIGN: ``report.json``, ``estimates.csv`` and ``report.html``.

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
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np

from common.jsonsafe import json_safe
from estimators.residual import NOT_OFFERED, ResidualResult
from estimators.residual_families import FAMILIES as DRIVE_FAMILIES
from estimators.residual_two_inertia import NOT_OFFERED_TWO_INERTIA, TwoInertiaResult
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
    "offset": "a constant effort (a sensor or amplifier offset, gravity on a tilted axis)",
    "inertia": "mass / inertia not in the nominal model",
    "viscous": "viscous friction, proportional to speed",
    "coulomb_asymmetry": "friction that differs by direction: a Coulomb level and a "
    "viscous coefficient for each direction (Fc_pos/Fc_neg, Fv_pos/Fv_neg)",
    "stribeck": "friction above the Coulomb level at low speed, fading over the Stribeck "
    "speed v_s (the same in both directions)",
    "position_periodic": "a force periodic in position (cogging, screw lead error)",
    "torque_ripple": "motor torque periodic in the motor angle",
    "backlash": "lost motion between motor and load at reversals",
    "harmonic": "a force periodic in time (a vibration, a disturbance at fixed frequency)",
    "delay": "the effort acts late relative to the motion (command-to-force lag)",
    "drift": "a slow change over time (warm-up of the lubricant, a thermal drift)",
    **{name: fam.meaning for name, fam in DRIVE_FAMILIES.items()},
}


def selection_text(res: ResidualResult | TwoInertiaResult) -> str:
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
    res: ResidualResult | TwoInertiaResult,
    validation: Mapping[str, Any] | None = None,
) -> dict[str, Any]:
    """The ``report.json`` object (DESIGN's contract keys plus details)."""
    two = isinstance(res, TwoInertiaResult)
    model = "rigid: tau = M*qdd + Fv*qd + Fc*sign(qd) + offset (IDIM-LS)"
    if isinstance(res, TwoInertiaResult):
        model = (
            "two_inertia: cutting force observer (seed 000 eq. 2-8) with the log's nominal "
            f"parameters; residual against {res.reference}; error over the force residual "
            "and the twist disagreement T_sK - T_sM"
        )
    rep: dict[str, Any] = {
        "log": str(log.path),
        "model": model,
        "kind": "two_inertia" if two else "rigid",
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
        # the selected effects in order, each with its physical meaning and parameters
        "effects": [
            {"name": c.name, "meaning": MEANING.get(c.name, ""), "params": c.params}
            for e in res.effects
            for c in res.candidates
            if c.name == e.name
        ],
        "unexplained": list(res.unexplained),
        # canonical families this kind does not offer, and why
        "not_offered": dict(NOT_OFFERED_TWO_INERTIA if two else NOT_OFFERED),
        "parameters_before": dict(zip(res.names_before, map(float, res.theta_before))),
        "parameters_after": dict(zip(res.names_after, map(float, res.theta_after))),
        "units": log.units,
        "indistinguishable": [dict(a) for a in res.indistinguishable],
        "selection_test": selection_text(res),
        "score": "relative reduction of the held-out mean square error (1 - mse_after/"
        "mse_before) at the round the candidate was last scored (report figure only: the "
        "held-out end takes no part in the selection)",
    }
    if isinstance(res, TwoInertiaResult):
        rep["rms_force_before"] = res.rms_force_before
        rep["rms_force_after"] = res.rms_force_after
        rep["rms_twist_before"] = res.rms_twist_before
        rep["rms_twist_after"] = res.rms_twist_after
        rep["observer_effects"] = [
            {"name": e.name, "side": e.side, "shape": dict(e.shape), "coef": list(e.coef)}
            for e in res.effects
        ]
    if validation is not None:
        rep["validation"] = dict(validation)
    return json_safe(rep)


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


def _figures(
    res: ResidualResult | TwoInertiaResult, unit: str, pos_unit: str = ""
) -> list[tuple[str, str]]:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

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


def report_html(rep: Mapping[str, Any], figures: list[tuple[str, str]]) -> str:
    """A self-contained page: numbers, candidate table, figures (PNG as base64)."""
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
        f"<tr><td>{_fmt(e['name'])}</td><td>{_fmt(e['meaning'])}</td>"
        f"<td>{_fmt(', '.join(f'{k}={_fmt(v)}' for k, v in e['params'].items()))}</td></tr>"
        for e in rep.get("effects", [])
    )
    unexpl = (
        "".join(f"<li>{_fmt(describe_structure(u))}</li>" for u in rep["unexplained"])
        or "<li>none above the reporting threshold</li>"
    )
    unexpl += "".join(
        f"<li>not offered: {_fmt(k)} — {_fmt(v)}</li>" for k, v in rep["not_offered"].items()
    )
    val = ""
    if "validation" in rep:
        v = rep["validation"]
        val = (
            f"<h2>Validation on {_fmt(v['log'])}</h2><p>rms {_fmt(v['rms_before'])} → "
            f"{_fmt(v['rms_after'])}; relerr {_fmt(v['relerr_before'])} % → "
            f"{_fmt(v['relerr_after'])} %</p>"
        )
    ambig = "".join(
        f"<p><b>Indistinguishable on this record: {_fmt(' and '.join(a['families']))}</b> "
        f"({_fmt(a['installed'])} installed). {_fmt(a['why'])}. To tell them apart: "
        f"{_fmt(a['excitation'])}.</p>"
        for a in rep.get("indistinguishable", [])
    )
    figs = "".join(
        f"<h3>{html.escape(t)}</h3><img alt='{html.escape(t)}' src='data:image/png;base64,{b}'>"
        for t, b in figures
    )
    return f"""<!doctype html>
<html lang="en"><head><meta charset="utf-8"><title>cutwatch residual report</title>
<style>body{{font-family:sans-serif;max-width:1000px;margin:auto}}
table{{border-collapse:collapse}}td,th{{border:1px solid #ccc;padding:2px 6px}}</style>
</head><body>
<h1>Residual report: {_fmt(rep["log"])}</h1>
<p>Model: {_fmt(rep["model"])}. Held out: t = {_fmt(rep["holdout"]["start"])} …
{_fmt(rep["holdout"]["stop"])} s.</p>
<p><b>Held-out rms {_fmt(rep["rms_before"])} → {_fmt(rep["rms_after"])}</b>;
relerr {_fmt(rep["relerr_before"])} % → {_fmt(rep["relerr_after"])} %.
Selected: {_fmt(", ".join(rep["selected"]) or "none")}.</p>
<p>Selection: {_fmt(rep["selection_test"])}.</p>
<h2>Selected effects</h2><table><tr><th>effect</th><th>physical meaning</th>
<th>parameters</th></tr>{effects}</table>
<h2>Parameters</h2><table><tr><th>name</th><th>before</th><th>after</th></tr>{params}</table>
{ambig}
<h2>Candidates</h2><table><tr><th>name</th><th>selected</th><th>CV effect</th>
<th>p</th><th>passed</th><th>held-out score</th><th>t</th>
<th>rms before</th><th>rms after</th><th>parameters</th><th>note</th></tr>{rows}</table>
<h2>Unexplained structure</h2><ul>{unexpl}</ul>
{val}
<h2>Figures</h2>{figs}
</body></html>
"""


def write_report(
    out_dir: Path,
    log: MeasuredLog,
    res: ResidualResult | TwoInertiaResult,
    validation: Mapping[str, Any] | None = None,
) -> dict[str, Any]:
    """Write ``report.json``, ``estimates.csv`` and ``report.html`` into ``out_dir``."""
    rep = report_dict(log, res, validation)
    figs = _figures(res, log.units.get("effort", ""), log.units.get("position", ""))
    page = report_html(rep, figs)
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
