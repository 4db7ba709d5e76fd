"""Monte Carlo of the residual loop's effect selection (issue 12, item 5).

Every case is one seed of one family at one record length, for both kinds of log:

* ``rigid``: the closed-form rigid axis of :func:`server.experiments.residual_logs.rigid_log`
  (1 kHz), analysed by :func:`estimators.residual.analyse_rigid`;
* ``two_inertia``: the simulator as ``cutwatch simulate --seed N`` runs it
  (:func:`server.experiments.residual_logs.simulate_stage`, 2.5 kHz), analysed by
  :func:`estimators.residual_two_inertia.analyse_two_inertia` against its ``f_ext``.

A seed draws the motion program, the noise and the effect's magnitude (x 0.7 ... 1.3 of
the default) and phase. Rows per kind, family and length:

* ``right_first``: the first selected family is the true one (``none``: nothing
  selected);
* ``right_or_indistinguishable``: ``right_first``, or the report names the true family
  as indistinguishable on this record from the one installed first;
* ``nothing``: nothing selected; ``spurious``: a family other than the true one (and
  not named indistinguishable from it) selected; on ``none`` that is the false-positive
  rate;
* ``median_ratio``: median over seeds of the held-out rms after / before, measured where
  the effect acts (Stribeck: load or axis speed below twice its Stribeck velocity;
  every other family: the whole held-out end).

Checks (DESIGN's and the issue's targets, every length): right first (or rightly
indistinguishable) >= 95 %, false positives on ``none`` <= 5 %, spurious extras
<= 5 %, median ratio <= 0.5.
"""

from __future__ import annotations

import math
import multiprocessing as mp
import os
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from server.experiments.reproduction import Check, Reproduction, Row
from server.experiments.residual_logs import (
    RIGID_EFFECTS,
    rigid_log,
    simulate_stage,
    stage_case,
)

NAME = "residual-selection"
SOURCE = (
    "issue 12 item 5: Monte Carlo of the residual selection (no paper; targets of "
    "DESIGN's performance budget and the issue)"
)

RIGID_FAMILIES: tuple[str, ...] = ("none", *RIGID_EFFECTS)
STAGE_FAMILIES: tuple[str, ...] = (
    "none",
    "offset",
    "coulomb_asymmetry",
    "stribeck",
    "position_periodic",
    "torque_ripple",
    "backlash",
)
LENGTHS: tuple[float, ...] = (10.0, 30.0, 100.0)
SEEDS = 20
QUICK_LENGTHS: tuple[float, ...] = (10.0,)
QUICK_SEEDS = 3
WORKERS = 2
#: Stribeck velocity of the closed-form rigid log [m/s]
RIGID_STRIBECK_V = 0.01

#: row names (KIND: rigid or two_inertia; LEN: 10s, 30s, 100s; --quick: 10s only)
ROWS = (
    "KIND.FAMILY.LEN.right_first",
    "KIND.FAMILY.LEN.right_or_indistinguishable",
    "KIND.FAMILY.LEN.nothing_selected",
    "KIND.FAMILY.LEN.spurious_extras",
    "KIND.none.LEN.false_positives",
    "KIND.FAMILY.LEN.median_ratio",
)

TARGET_RIGHT = 0.95
TARGET_FP = 0.05
TARGET_SPURIOUS = 0.05
TARGET_RATIO = 0.5


@dataclass(frozen=True)
class Case:
    kind: str
    family: str
    seconds: float
    seed: int


def _ratio(sq0: np.ndarray, sq1: np.ndarray) -> float:
    if len(sq0) == 0 or not float(np.mean(sq0)) > 0:
        return math.nan
    return math.sqrt(float(np.mean(sq1)) / float(np.mean(sq0)))


def run_case(case: Case) -> dict[str, Any]:
    """Generate and analyse one case; the selection, the ambiguity and the ratio."""
    t0 = time.perf_counter()
    if case.kind == "rigid":
        from estimators.residual import analyse_rigid

        n = int(round(case.seconds * 1000))
        cols = rigid_log(case.family, n, case.seed)
        res = analyse_rigid(cols["q_m"], cols["tau_m"], cols["t"], 1e-3)
        hold = res.t_dec >= res.holdout_start
        where = hold.copy()
        if case.family == "stribeck":
            where &= np.abs(res.qd_dec) < 2.0 * RIGID_STRIBECK_V
        sq0 = res.residual_before_dec[where] ** 2
        sq1 = res.residual_after_dec[where] ** 2
        selected = [e.name for e in res.effects]
        groups = [[str(f) for f in a["families"]] for a in res.indistinguishable]  # type: ignore[attr-defined]
        installed = [str(a["installed"]) for a in res.indistinguishable]
    else:
        from estimators.force_observer import LoadParams, ObserverParams
        from estimators.residual_two_inertia import analyse_two_inertia

        effects = [] if case.family == "none" else [case.family]
        sc = stage_case(effects, case.seed)
        cols, side, truth = simulate_stage(sc, case.seconds, seed=case.seed)
        nom = side["nominal"]
        op = ObserverParams(
            J_M=nom["J_M"],
            B_M=nom["B_M"],
            F_CM=nom["F_CM"],
            K=nom["K"],
            sample_time=side["sample_time"],
            encoder_resolution=side["encoder_resolution"],
        )
        lp = LoadParams(J_L=nom["J_L"], B_L=nom["B_L"], F_CL=nom["F_CL"])
        res2 = analyse_two_inertia(
            cols["t"], cols["tau_m"], cols["q_m"], cols["q_l"], op, lp, f_ext=cols["f_ext"]
        )
        where = np.ones(len(res2.hold_sq_before), dtype=bool)
        if case.family == "stribeck":
            vs = float(truth["effect_parameters"]["stribeck_velocity"])
            where = np.abs(res2.hold_speed) < 2.0 * vs
        sq0, sq1 = res2.hold_sq_before[where], res2.hold_sq_after[where]
        selected = [e.name for e in res2.effects]
        groups = [[str(f) for f in a["families"]] for a in res2.indistinguishable]  # type: ignore[attr-defined]
        installed = [str(a["installed"]) for a in res2.indistinguishable]
    return {
        "kind": case.kind,
        "family": case.family,
        "seconds": case.seconds,
        "seed": case.seed,
        "selected": selected,
        "groups": groups,
        "installed": installed,
        "ratio": _ratio(sq0, sq1),
        "elapsed": time.perf_counter() - t0,
    }


def score(out: dict[str, Any]) -> dict[str, float]:
    """Per-case outcomes (0/1) of one analysed case."""
    fam, sel = out["family"], out["selected"]
    twins = {fam}
    for g in out["groups"]:
        if fam in g:
            twins |= set(g)
    if fam == "none":
        right = float(not sel)
        indist = right
        spurious = float(bool(sel))
    else:
        right = float(sel[:1] == [fam])
        first_twin = (
            bool(sel) and sel[0] in twins and any(fam in g and sel[0] in g for g in out["groups"])
        )
        indist = float(right or first_twin)
        spurious = float(any(s not in twins for s in sel))
    return {
        "right_first": right,
        "right_or_indistinguishable": indist,
        "nothing": float(not sel),
        "spurious": spurious,
    }


def _cases(quick: bool) -> list[Case]:
    lengths = QUICK_LENGTHS if quick else LENGTHS
    seeds = QUICK_SEEDS if quick else SEEDS
    out = []
    for kind, fams in (("two_inertia", STAGE_FAMILIES), ("rigid", RIGID_FAMILIES)):
        for sec in lengths:
            for fam in fams:
                for s in range(1, seeds + 1):
                    out.append(Case(kind, fam, sec, s))
    # longest first: the pool's tail is then short cases
    out.sort(key=lambda c: -(c.seconds * (2.5 if c.kind == "two_inertia" else 1.0)))
    return out


def _init_worker() -> None:
    import warnings

    warnings.simplefilter("ignore")


def run_cases(cases: list[Case], *, progress: bool, workers: int = WORKERS) -> list[dict[str, Any]]:
    """Analyse every case with at most ``workers`` processes (spawned, one BLAS thread)."""
    from tqdm import tqdm

    # one BLAS thread per worker: two workers on a 2-core machine
    os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
    os.environ.setdefault("OMP_NUM_THREADS", "1")
    results: list[dict[str, Any]] = []
    with tqdm(total=len(cases), desc=NAME, unit="case", disable=not progress, leave=False) as bar:
        if workers <= 1:
            for c in cases:
                results.append(run_case(c))
                bar.update(1)
        else:
            ctx = mp.get_context("spawn")
            with ctx.Pool(min(workers, WORKERS), initializer=_init_worker) as pool:
                for r in pool.imap_unordered(run_case, cases):
                    results.append(r)
                    bar.update(1)
    return results


def summarise(results: list[dict[str, Any]]) -> dict[tuple[str, str, float], dict[str, float]]:
    """Rates and median ratio per (kind, family, length)."""
    groups: dict[tuple[str, str, float], list[dict[str, Any]]] = {}
    for r in results:
        groups.setdefault((r["kind"], r["family"], float(r["seconds"])), []).append(r)
    out = {}
    for key, rs in groups.items():
        sc = [score(r) for r in rs]
        ratios = [r["ratio"] for r in rs if math.isfinite(r["ratio"])]
        out[key] = {
            **{k: float(np.mean([s[k] for s in sc])) for k in sc[0]},
            "median_ratio": float(np.median(ratios)) if ratios else math.nan,
            "seeds": float(len(rs)),
            "seconds_per_case": float(np.mean([r["elapsed"] for r in rs])),
        }
    return out


def _plot(table: dict[tuple[str, str, float], dict[str, float]], plot_dir: Path) -> str:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    keys = sorted({(k[0], k[1]) for k in table})
    lengths = sorted({k[2] for k in table})
    metrics = (
        ("right_or_indistinguishable", "right first (or rightly indistinguishable)", "RdYlGn"),
        ("nothing", "nothing selected", "RdYlGn_r"),
        ("spurious", "spurious extras / false positives", "RdYlGn_r"),
        ("median_ratio", "median held-out ratio (where the effect acts)", "RdYlGn_r"),
    )
    fig, axes = plt.subplots(1, 4, figsize=(17, 0.42 * len(keys) + 2.2), sharey=True)
    for ax, (m, title, cmap) in zip(axes, metrics):
        data = np.array(
            [[table.get((k[0], k[1], ln), {}).get(m, np.nan) for ln in lengths] for k in keys]
        )
        colour = data.copy()
        for i, k in enumerate(keys):
            if k[1] == "none":
                if m == "median_ratio":  # nothing to explain: no ratio
                    data[i] = np.nan
                    colour[i] = np.nan
                elif m == "nothing":  # on none, nothing selected is the right answer
                    colour[i] = 1.0 - colour[i]
        ax.imshow(colour, cmap=cmap, vmin=0.0, vmax=1.0, aspect="auto")
        for i in range(data.shape[0]):
            for j in range(data.shape[1]):
                v = data[i, j]
                txt = (
                    "-"
                    if not np.isfinite(v)
                    else (f"{v:.2f}" if m == "median_ratio" else f"{100 * v:.0f}")
                )
                ax.text(j, i, txt, ha="center", va="center", fontsize=8)
        ax.set_xticks(range(len(lengths)), [f"{ln:g} s" for ln in lengths])
        ax.set_title(title, fontsize=9)
    axes[0].set_yticks(range(len(keys)), [f"{k[0]}.{k[1]}" for k in keys], fontsize=8)
    fig.suptitle("residual selection, Monte Carlo (% of seeds; ratio: rms after / before)")
    fig.tight_layout()
    plot_dir.mkdir(parents=True, exist_ok=True)
    path = plot_dir / "residual_selection.png"
    fig.savefig(path, dpi=100)
    plt.close(fig)
    return str(path)


def build(table: dict[tuple[str, str, float], dict[str, float]]) -> Reproduction:
    """Rows and checks of the reproduction from the summarised table."""
    rep = Reproduction(NAME, SOURCE)
    for (kind, fam, sec), v in sorted(table.items()):
        base = f"{kind}.{fam}.{sec:g}s"
        cond = f"{int(v['seeds'])} seeds, {v['seconds_per_case']:.1f} s per case"
        rep.rows.append(Row(f"{base}.right_first", 100 * v["right_first"], None, "%", cond))
        if fam != "none":
            rep.rows.append(
                Row(
                    f"{base}.right_or_indistinguishable",
                    100 * v["right_or_indistinguishable"],
                    None,
                    "%",
                    cond,
                )
            )
        rep.rows.append(Row(f"{base}.nothing_selected", 100 * v["nothing"], None, "%", cond))
        name = "false_positives" if fam == "none" else "spurious_extras"
        rep.rows.append(Row(f"{base}.{name}", 100 * v["spurious"], None, "%", cond))
        if fam != "none":
            rep.rows.append(Row(f"{base}.median_ratio", v["median_ratio"], None, "-", cond))
        # checks: the targets
        if fam == "none":
            rep.checks.append(
                Check(
                    f"{base}.false_positives <= 5 %",
                    v["spurious"] <= TARGET_FP,
                    100 * v["spurious"],
                    100 * TARGET_FP,
                )
            )
            continue
        rep.checks.append(
            Check(
                f"{base}.right_first (or rightly indistinguishable) >= 95 %",
                v["right_or_indistinguishable"] >= TARGET_RIGHT,
                100 * v["right_or_indistinguishable"],
                100 * TARGET_RIGHT,
            )
        )
        rep.checks.append(
            Check(
                f"{base}.spurious_extras <= 5 %",
                v["spurious"] <= TARGET_SPURIOUS,
                100 * v["spurious"],
                100 * TARGET_SPURIOUS,
            )
        )
        ratio = v["median_ratio"]
        rep.checks.append(
            Check(f"{base}.median_ratio <= 0.5", bool(ratio <= TARGET_RATIO), ratio, TARGET_RATIO)
        )
    return rep


def run(
    *, quick: bool = False, plot_dir: Path | None = None, progress: bool = True
) -> Reproduction:
    """The Monte Carlo (``quick``: 3 seeds of 10 s records, the same checks)."""
    results = run_cases(_cases(quick), progress=progress)
    table = summarise(results)
    rep = build(table)
    if plot_dir is not None:
        rep.figures.append(_plot(table, plot_dir))
    return rep
