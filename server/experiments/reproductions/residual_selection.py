"""Monte Carlo of the residual loop's effect selection (issue 12, item 5).

Every case is one seed of one family at one record length, for both kinds of log:

* ``rigid``: the closed-form rigid axis of :func:`server.experiments.residual_logs.rigid_log`
  (1 kHz), analysed by :func:`estimators.residual.engine.analyse` through
  :class:`estimators.residual.rigid.RigidModel`;
* ``two_inertia``: the simulator as ``cutwatch simulate --seed N`` runs it
  (:func:`server.experiments.residual_logs.simulate_stage`, 2.5 kHz), analysed by
  :class:`estimators.residual.two_inertia.TwoInertiaModel` against its ``f_ext``.

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
  the effect acts: in time, Stribeck only below twice its Stribeck velocity (every other
  family: the whole held-out end); in the two-inertia observer, a load-side family
  (offset, coulomb_asymmetry, stribeck, position_periodic) only in the force estimate,
  since its twist column is zero, a motor- or shaft-side one (torque_ripple, backlash)
  in both channels. ``median_ratio_both_channels`` keeps the mean of both channels for
  every family (the measure before this distinction);
* ``median_effect_free_ratio``: the same seeds' records without the effect through the
  nominal model, their rms there over the effect records' nominal rms: where a perfect
  model of the effect alone lands (the nominal model's own floor).

The full run keeps each finished case in a JSON-lines cache keyed by the hash of the
code it depends on (:func:`cache_path`), so an interrupted run resumes.

Checks (the targets of docs/design.md and the issue, every length): right first (or rightly
indistinguishable) >= 95 %, false positives on ``none`` <= 5 %, spurious extras
<= 5 %, median ratio <= 0.5.
"""

from __future__ import annotations

import functools
import hashlib
import json
import math
import multiprocessing as mp
import os
import sys
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal, TypedDict

import numpy as np

from machine.effects import EFFECT_NAMES
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
    "docs/design.md's performance budget and the issue)"
)

RIGID_FAMILIES: tuple[str, ...] = ("none", *RIGID_EFFECTS)
#: every effect the simulator can produce (machine.effects.EFFECT_NAMES), plus none
STAGE_FAMILIES: tuple[str, ...] = ("none", *EFFECT_NAMES)
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
    "KIND.FAMILY.LEN.median_effect_free_ratio",
    "two_inertia.FAMILY.LEN.median_ratio_both_channels",
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


class CaseResult(TypedDict):
    """One analysed case (:func:`run_case`; a line of the full run's cache): the case,
    the effects selected, the groups found indistinguishable and which of each was
    installed, the held-out ratios (NaN: none) and the seconds it took."""

    kind: str
    family: str
    seconds: float
    seed: int
    selected: list[str]
    groups: list[list[str]]
    installed: list[str]
    ratio: float
    ratio_both_channels: float
    effect_free_ratio: float
    elapsed: float


#: the ratios a group's median is taken of (:func:`summarise`)
Ratio = Literal["ratio", "effect_free_ratio", "ratio_both_channels"]


def _ratio(sq0: np.ndarray, sq1: np.ndarray) -> float:
    if len(sq0) == 0 or not float(np.mean(sq0)) > 0:
        return math.nan
    return math.sqrt(float(np.mean(sq1)) / float(np.mean(sq0)))


def _rigid(family: str, seconds: float, seed: int, max_effects: int | None = None) -> Any:
    from estimators.residual.engine import ResidualParams, analyse
    from estimators.residual.rigid import RigidModel

    cols = rigid_log(family, int(round(seconds * 1000)), seed)
    model = RigidModel(cols["q_m"], cols["tau_m"], cols["t"], 1e-3)
    return analyse(model, ResidualParams(max_effects=max_effects))


def _rigid_where(res: Any, family: str) -> np.ndarray:
    where = np.asarray(res.t_dec >= res.holdout_start)
    if family == "stribeck":
        where = where & (np.abs(res.qd_dec) < 2.0 * RIGID_STRIBECK_V)
    return where


def _stage(family: str, seconds: float, seed: int, max_effects: int | None = None) -> Any:
    from estimators.residual.engine import ResidualParams, analyse
    from estimators.residual.two_inertia import TwoInertiaModel, nominal_observer

    effects = [] if family == "none" else [family]
    cols, side, _ = simulate_stage(stage_case(effects, seed), seconds, seed=seed)
    op, lp = nominal_observer(side["nominal"], side["sample_time"], side["encoder_resolution"])
    model = TwoInertiaModel(
        cols["t"], cols["tau_m"], cols["q_m"], cols["q_l"], op, lp, f_ext=cols["f_ext"]
    )
    return analyse(model, ResidualParams(max_effects=max_effects))


@functools.lru_cache(maxsize=4)
def _twin(kind: str, seconds: float, seed: int) -> Any:
    """The same seed's record without any effect through the nominal model only (the
    cases of one seed run next to each other, so a worker reuses it)."""
    if kind == "rigid":
        return _rigid("none", seconds, seed, max_effects=0)
    return _stage("none", seconds, seed, max_effects=0)


def _stage_sq(res: Any, family: str, seed: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Squared held-out errors before/after where ``family`` acts, and over both channels.

    Where: a load-side family (its twist column is zero, ``SIDES``) acts on the force
    estimate only, so its ratio is the force channel's; motor- and shaft-side families
    act on both channels. Stribeck: only rows below twice its Stribeck velocity.
    """
    from estimators.observer_effects import SIDES

    where = np.ones(len(res.hold_sq_before), dtype=bool)
    if family == "stribeck":
        vs = float(stage_case(["stribeck"], seed).effects.stribeck_velocity)
        where = np.abs(res.hold_speed) < 2.0 * vs
    if SIDES.get(family, "load") == "load":
        return res.hold_sq_force_before[where], res.hold_sq_force_after[where], where
    return res.hold_sq_before[where], res.hold_sq_after[where], where


def run_case(case: Case) -> CaseResult:
    """Generate and analyse one case: the selection, the ambiguity, the held-out ratio
    where the effect acts, and the attainable ratio.

    The effect-free ratio is where a perfect model of the effect alone would land: the
    same seed's record *without* the effect (same motion and noise) through the nominal
    model, its held-out rms where the effect would act over the effect record's nominal
    rms there (the nominal model's own floor: noise, the observer's error). A fitted
    effect can go below it when it also absorbs some of that floor.
    """
    t0 = time.perf_counter()
    floor = math.nan
    both = math.nan
    if case.kind == "rigid":
        res = _rigid(case.family, case.seconds, case.seed)
        where = _rigid_where(res, case.family)
        sq0 = res.residual_before_dec[where] ** 2
        sq1 = res.residual_after_dec[where] ** 2
        if case.family != "none":
            twin = _twin("rigid", case.seconds, case.seed)
            tw = _rigid_where(twin, case.family)
            floor = _ratio(sq0, twin.residual_before_dec[tw] ** 2)
    else:
        res = _stage(case.family, case.seconds, case.seed)
        sq0, sq1, where = _stage_sq(res, case.family, case.seed)
        both = _ratio(res.hold_sq_before[where], res.hold_sq_after[where])
        if case.family != "none":
            twin = _twin("two_inertia", case.seconds, case.seed)
            f0, _, _ = _stage_sq(twin, case.family, case.seed)
            floor = _ratio(sq0, f0)
    selected = [e.name for e in res.effects]
    groups = [[str(f) for f in a["families"]] for a in res.indistinguishable]
    installed = [str(a["installed"]) for a in res.indistinguishable]
    return {
        "kind": case.kind,
        "family": case.family,
        "seconds": case.seconds,
        "seed": case.seed,
        "selected": selected,
        "groups": groups,
        "installed": installed,
        "ratio": _ratio(sq0, sq1),
        "ratio_both_channels": both,
        "effect_free_ratio": floor,
        "elapsed": time.perf_counter() - t0,
    }


def score(out: CaseResult) -> dict[str, float]:
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
            for s in range(1, seeds + 1):
                for fam in fams:
                    out.append(Case(kind, fam, sec, s))
    # longest first: the pool's tail is then short cases (stable: a seed's families
    # stay next to each other)
    out.sort(key=lambda c: -(c.seconds * (2.5 if c.kind == "two_inertia" else 1.0)))
    return out


def _init_worker() -> None:
    import warnings

    warnings.simplefilter("ignore")


#: the code a case's outcome depends on (its hash keys the case cache): these packages
#: and files, and the functions of this module that make a case (not its table or plot)
_CODE = (
    "estimators",
    "machine",
    "common",
    "server/experiments/residual_logs.py",
)


def code_version() -> str:
    """Hash of the sources a case's outcome depends on (estimators, machine, the logs and
    the case functions of this module)."""
    import inspect

    root = Path(__file__).resolve().parents[3]
    h = hashlib.sha256()
    for rel in _CODE:
        p = root / rel
        for f in sorted(p.rglob("*.py")) if p.is_dir() else [p]:
            h.update(str(f.relative_to(root)).encode())
            h.update(f.read_bytes())
    for fn in (_ratio, _rigid, _rigid_where, _stage, _twin, _stage_sq, run_case):
        h.update(inspect.getsource(fn).encode())
    h.update(repr((RIGID_STRIBECK_V, RIGID_FAMILIES, STAGE_FAMILIES)).encode())
    return h.hexdigest()[:16]


def cache_path() -> Path:
    """Where the full run keeps finished cases: ``$CUTWATCH_CACHE_DIR`` or
    ``~/.cache/cutwatch``, one JSON-lines file per code version."""
    base = os.environ.get("CUTWATCH_CACHE_DIR") or str(Path.home() / ".cache" / "cutwatch")
    return Path(base) / NAME / f"{code_version()}.jsonl"


def _key(c: Case | CaseResult) -> tuple[str, str, float, int]:
    if isinstance(c, Case):
        return (c.kind, c.family, float(c.seconds), int(c.seed))
    return (str(c["kind"]), str(c["family"]), float(c["seconds"]), int(c["seed"]))


def _load_cache(path: Path) -> dict[tuple[str, str, float, int], CaseResult]:
    out: dict[tuple[str, str, float, int], CaseResult] = {}
    if not path.is_file():
        return out
    for line in path.read_text().splitlines():
        try:
            r = json.loads(line)
            out[_key(r)] = r
        except (ValueError, KeyError, TypeError):
            continue  # a line cut short by an interrupted run
    return out


def run_cases(
    cases: list[Case], *, progress: bool, workers: int = WORKERS, cache: Path | None = None
) -> list[CaseResult]:
    """Analyse every case with at most ``workers`` processes (spawned, one BLAS thread).

    With ``cache`` (a JSON-lines file), cases found there are not run again and every
    finished case is appended at once: an interrupted run resumes where it stopped.
    """
    from tqdm import tqdm

    done = _load_cache(cache) if cache is not None else {}
    results: list[CaseResult] = [done[_key(c)] for c in cases if _key(c) in done]
    cases = [c for c in cases if _key(c) not in done]
    sink = None
    if cache is not None:
        cache.parent.mkdir(parents=True, exist_ok=True)
        cut = (
            cache.is_file() and cache.stat().st_size > 0 and not cache.read_bytes().endswith(b"\n")
        )
        sink = cache.open("a")
        if cut:  # the last line of an interrupted run: start on a fresh line
            sink.write("\n")
        if results and progress:
            print(f"{NAME}: {len(results)} cases from {cache}", file=sys.stderr)

    def keep(r: CaseResult) -> None:
        results.append(r)
        if sink is not None:
            sink.write(json.dumps(r) + "\n")
            sink.flush()

    # one BLAS thread per worker: two workers on a 2-core machine
    os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
    os.environ.setdefault("OMP_NUM_THREADS", "1")
    try:
        with tqdm(
            total=len(cases), desc=NAME, unit="case", disable=not progress or not cases, leave=False
        ) as bar:
            if workers <= 1 or len(cases) <= 1:
                for c in cases:
                    keep(run_case(c))
                    bar.update(1)
            else:
                ctx = mp.get_context("spawn")
                with ctx.Pool(min(workers, WORKERS), initializer=_init_worker) as pool:
                    for r in pool.imap_unordered(run_case, cases, chunksize=1):
                        keep(r)
                        bar.update(1)
    finally:
        if sink is not None:
            sink.close()
    return results


def summarise(results: list[CaseResult]) -> dict[tuple[str, str, float], dict[str, float]]:
    """Rates and median ratio per (kind, family, length)."""
    groups: dict[tuple[str, str, float], list[CaseResult]] = {}
    for r in results:
        groups.setdefault((r["kind"], r["family"], float(r["seconds"])), []).append(r)
    out = {}
    for key, rs in groups.items():
        sc = [score(r) for r in rs]

        def med(k: Ratio, rs: list[CaseResult] = rs) -> float:
            v = [float(r[k]) for r in rs if k in r and math.isfinite(float(r[k]))]
            return float(np.median(v)) if v else math.nan

        out[key] = {
            **{k: float(np.mean([s[k] for s in sc])) for k in sc[0]},
            "median_ratio": med("ratio"),
            "median_effect_free_ratio": med("effect_free_ratio"),
            "median_ratio_both_channels": med("ratio_both_channels"),
            "seeds": float(len(rs)),
            "seconds_per_case": float(np.mean([r["elapsed"] for r in rs])),
        }
    return out


def _misses(metric: str, family: str, v: float) -> bool:
    """Whether this cell of the heatmap misses one of the checks' targets."""
    if not math.isfinite(v):
        return False
    if metric == "right_or_indistinguishable":
        return family != "none" and v < TARGET_RIGHT
    if metric == "spurious":
        return v > (TARGET_FP if family == "none" else TARGET_SPURIOUS)
    if metric == "median_ratio":
        return family != "none" and not v <= TARGET_RATIO
    return False


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
        ("median_effect_free_ratio", "the same without the effect (its floor)", "RdYlGn_r"),
    )
    fig, axes = plt.subplots(1, 5, figsize=(21, 0.42 * len(keys) + 2.2), sharey=True)
    for ax, (m, title, cmap) in zip(axes, metrics):
        data = np.array(
            [[table.get((k[0], k[1], ln), {}).get(m, np.nan) for ln in lengths] for k in keys]
        )
        colour = data.copy()
        for i, k in enumerate(keys):
            if k[1] == "none":
                if m.startswith("median"):  # nothing to explain: no ratio
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
                    else (f"{v:.2f}" if m.startswith("median") else f"{100 * v:.0f}")
                )
                missed = _misses(m, keys[i][1], v)
                ax.text(
                    j, i, txt + (" ✗" if missed else ""), ha="center", va="center", fontsize=8,
                    fontweight="bold" if missed else "normal",
                )  # fmt: skip
                if missed:  # a check of the targets that does not hold
                    ax.add_patch(
                        plt.Rectangle(
                            (j - 0.5, i - 0.5), 1, 1, fill=False, edgecolor="red", linewidth=2
                        )
                    )
        ax.set_xticks(range(len(lengths)), [f"{ln:g} s" for ln in lengths])
        ax.set_title(title, fontsize=9)
    axes[0].set_yticks(range(len(keys)), [f"{k[0]}.{k[1]}" for k in keys], fontsize=8)
    fig.suptitle(
        "residual selection, Monte Carlo (% of seeds; ratio: rms after / before; "
        "red ✗: a target missed)"
    )
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
            rep.rows.append(
                Row(
                    f"{base}.median_effect_free_ratio",
                    v["median_effect_free_ratio"],
                    None,
                    "-",
                    cond + "; the same seeds without the effect, nominal model",
                )
            )
            if kind == "two_inertia":
                rep.rows.append(
                    Row(
                        f"{base}.median_ratio_both_channels",
                        v["median_ratio_both_channels"],
                        None,
                        "-",
                        cond + "; force and twist channels together",
                    )
                )
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
    """The Monte Carlo (``quick``: 3 seeds of 10 s records, the same checks).

    The full run keeps every finished case in :func:`cache_path` (keyed by the code's
    hash) and resumes from it; ``--quick`` always computes.
    """
    results = run_cases(_cases(quick), progress=progress, cache=None if quick else cache_path())
    table = summarise(results)
    rep = build(table)
    if plot_dir is not None:
        rep.figures.append(_plot(table, plot_dir))
    return rep
