"""Why the live identification is wrong, and what the segment identifier makes of it.

Issue 13 items 1-3. Runs the default live scenario's pipeline
(:class:`server.pipeline.live_pipeline.LivePipeline`, 125-sample blocks as live) offline
and scores, every 10 ms after the first 30 s, the identified J_L, B_L, F_CL of the ordinary
RLS (seed 000), the switching RLS (seed 001) and the gated segment identifier
(:mod:`estimators.segment_id`) against the truth: median absolute relative error, share
of time within 10 / 20 / 30 %, bias (median signed relative error); for the segment
identifier also the 95 % interval's coverage and the share of time flagged excited.

Ablations: each suspect of the issue is switched off in turn, then all of them:

- ``spindle_steps``: the spindle's 80 % steps every 15 s (force gain and frequencies);
- ``wear_dc``: the cutting force's DC growing with tool wear (and its reset at a tool
  change);
- ``mass_removal``: the workpiece losing inertia (J_L falling by up to half, then a fresh
  blank);
- ``reversal_force``: the cutting force during the velocity reversals (the cutter is
  lifted from 0.3 s before to 0.5 s after every reversal).

Seeds vary the data: each seed draws the spindle speed (2700-3300 rpm), the feed
(0.9-1.1), the removal rate (1.5-2.5 %/s), the wear rate (0.35-0.65 min/s) and a current
noise (0.002-0.01 A rms, from the simulator's seeded generator); the knobs a user can set.

Also measured (item 3): at every spindle step, tool change and workpiece change, the
segment identifier's largest excursion from its interval just before the change, in
units of that interval's width, and whether the truth left the interval by more than its
width; and after every spindle step the time until both DFO amplitudes are back within
5 % of the truth (and stay for 0.1 s).

``python -m server.experiments.reproductions.live_identifiability --minutes 10 --seeds 5``
runs other lengths; ``cutwatch reproduce live-identifiability`` the standard one.
"""

from __future__ import annotations

import argparse
import math
import sys
import time
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from common.arrays import F64
from machine.stage import Trajectory
from server.experiments.reproduction import Check, Reproduction, Row, format_table
from server.pipeline.live_pipeline import LivePipeline
from server.pipeline.wear_passes import PASS_S

NAME = "live-identifiability"
SOURCE = "issue 13 (default live scenario); seed 000 eq. (14), seed 001 Fig. 6"
SUSPECTS = ("spindle_steps", "wear_dc", "mass_removal", "reversal_force")
#: "stepped_wear": the wear force as the issue measured it, in 1 % steps at the pass
#: starts (every second, so on every reversal) instead of the smooth ramp
CASES = ("default", *(f"no_{s}" for s in SUSPECTS), "none", "stepped_wear")
ESTIMATORS = ("adaptive", "switching", "segment")
PARAMS = ("J_L", "B_L", "F_CL")
ROWS = [
    "<case>.<estimator>.<J_L|B_L|F_CL>.<med_abs_err|within_10|within_20|within_30|bias>",
    "<case>.segment.<J_L|B_L|F_CL>.<coverage|excited|coverage_excited>",
    "events.<spindle|tool|workpiece>.<max_excursion|max_truth_miss>",
    "dfo.recovery_time.<median|max>",
]
BLOCK = 125  # the live block size (50 ms)
SKIP = 30.0  # the first 30 s are not scored (issue 13)
DECIM = 25  # scored every 10 ms
#: reversal_force off: the cutter is lifted from 1 s before to 1.5 s after every reversal
#: (longer than a reversal segment, so lifting and lowering it are separate events, each
#: told to the identifier as a known change of the cutting condition)
REV_PRE, REV_POST = 1.0, 1.5


def knobs_for(seed: int) -> dict[str, float]:
    """The knob values a seed draws (see the module docstring)."""
    g = np.random.default_rng(10_000 + seed)
    return {
        "spindle_rpm": float(g.uniform(2700.0, 3300.0)),
        "feed_scale": float(g.uniform(0.9, 1.1)),
        "removal_rate": float(g.uniform(1.5, 2.5)),
        "wear_rate": float(g.uniform(0.35, 0.65)),
        "current_noise": float(g.uniform(0.002, 0.01)),
    }


class AblatedPipeline(LivePipeline):
    """The default scenario with the named suspects switched off."""

    def __init__(self, off: frozenset[str], seed: int, vary: bool = True) -> None:
        self.off = frozenset(off)
        self._lifted = False
        super().__init__("default", seed=seed)
        if vary:
            for k, v in knobs_for(seed).items():
                self.set_knob(k, v)
        if "spindle_steps" in self.off:
            self.set_knob("spindle_changes", False)
        if "mass_removal" in self.off:
            self.set_knob("removal_rate", 0.0)

    def _near_reversal(self, t0: float, t1: float) -> bool:
        tr: Trajectory = self.run.sim.config.trajectory
        hp = tr.half_period
        m = max(round(0.5 * (t0 + t1) / hp), 1)
        return t1 > m * hp - REV_PRE and t0 < m * hp + REV_POST

    def _apply(self, t: float) -> None:
        tool = self.tool
        if tool is not None and "smooth_wear" in self.off and tool.state.gain_ramp[2] == t:
            # a pass starts at t: its force in 1 % steps (idempotent once stepped)
            g0, slope, _ = tool.state.gain_ramp
            mean = g0 + 0.5 * slope * PASS_S
            tool.state.gain_ramp = (round(mean / 0.01) * 0.01, 0.0, t)
        if tool is not None and "wear_dc" in self.off:
            tool.state.gain_ramp = (1.0, 0.0, 0.0)
        super()._apply(t)
        if "reversal_force" in self.off:
            lift = self._near_reversal(t, t + BLOCK * self.sample_time)
            if lift:
                f = self.run.sim.config.force
                self.run.sim.reconfigure(force=replace(f, gain=0.0))
                self._applied = ()  # re-apply the cutting force after the reversal
            if lift != self._lifted:
                self.run.note_disturbance(t)
            self._lifted = lift


@dataclass
class Trace:
    """Decimated series of one run (every DECIM-th sample)."""

    t: list[F64] = field(default_factory=list)
    truth: list[F64] = field(default_factory=list)
    est: dict[str, list[F64]] = field(default_factory=lambda: {e: [] for e in ESTIMATORS})
    lo: list[F64] = field(default_factory=list)
    hi: list[F64] = field(default_factory=list)
    exc: list[F64] = field(default_factory=list)
    # full-rate around events: (kind, t, arrays)
    events: list[tuple[str, float]] = field(default_factory=list)
    h: list[F64] = field(default_factory=list)  # t, h1, h2, h1_true, h2_true (full rate)

    def arrays(self) -> dict[str, F64]:
        out = {
            "t": np.concatenate(self.t),
            "truth": np.concatenate(self.truth),
            "lo": np.concatenate(self.lo),
            "hi": np.concatenate(self.hi),
            "exc": np.concatenate(self.exc),
            "h": np.concatenate(self.h),
        }
        for e in ESTIMATORS:
            out[e] = np.concatenate(self.est[e])
        return out


def run_case(off: frozenset[str], seed: int, minutes: float, *, progress: bool = False) -> Trace:
    """One run of the (ablated) default scenario, with its events noted."""
    p = AblatedPipeline(off, seed)
    n_blocks = int(round(minutes * 60.0 / (BLOCK * p.sample_time)))
    tr = Trace()
    prev_sf = p._spindle_factor(0.0)
    prev_tools = p.tools_changed
    prev_removed = p.workpiece_removed
    t_wall = time.perf_counter()
    for i in range(n_blocks):
        t0 = p.t
        o = p.step(BLOCK)
        sf = p._spindle_factor(t0)
        if sf != prev_sf:
            tr.events.append(("spindle", t0))
        prev_sf = sf
        if p.tools_changed != prev_tools:
            tr.events.append(("tool", t0))
            prev_tools = p.tools_changed
        if p.workpiece_removed < prev_removed:
            tr.events.append(("workpiece", t0))
        prev_removed = p.workpiece_removed
        s = slice(0, BLOCK, DECIM)
        tr.t.append(o["t"][s])
        tr.truth.append(np.column_stack([o[f"{q}_true"][s] for q in PARAMS]))
        for e in ("adaptive", "switching"):
            tr.est[e].append(np.column_stack([o[f"{q}_{e}"][s] for q in PARAMS]))
        tr.est["segment"].append(np.column_stack([o[f"{q}_seg"][s] for q in PARAMS]))
        tr.lo.append(np.column_stack([o[f"{q}_lo"][s] for q in PARAMS]))
        tr.hi.append(np.column_stack([o[f"{q}_hi"][s] for q in PARAMS]))
        tr.exc.append(np.column_stack([o[f"{q}_excited"][s] for q in PARAMS]))
        tr.h.append(np.column_stack([o["t"], o["h1_amp"], o["h2_amp"], o["h1_true"], o["h2_true"]]))
        if progress and i % 2400 == 0:
            el = time.perf_counter() - t_wall
            print(
                f"  {sorted(off) or ['default']} seed {seed}: {p.t:.0f} s ({el:.0f} s)",
                file=sys.stderr,
            )
    return tr


def scores(a: dict[str, F64]) -> dict[str, float]:
    """Accuracy of every estimator and the segment identifier's interval, after SKIP."""
    m = a["t"] >= SKIP
    out: dict[str, float] = {}
    for j, q in enumerate(PARAMS):
        truth = a["truth"][m, j]
        for e in ESTIMATORS:
            rel = (a[e][m, j] - truth) / truth
            out[f"{e}.{q}.med_abs_err"] = float(np.median(np.abs(rel)))
            for w in (10, 20, 30):
                out[f"{e}.{q}.within_{w}"] = float(np.mean(np.abs(rel) <= w / 100))
            out[f"{e}.{q}.bias"] = float(np.median(rel))
        cov = (a["lo"][m, j] <= truth) & (truth <= a["hi"][m, j])
        exc = a["exc"][m, j] > 0.5
        rel = np.abs(a["segment"][m, j] - truth) / truth
        out[f"segment.{q}.coverage"] = float(np.mean(cov))
        out[f"segment.{q}.excited"] = float(np.mean(exc))
        out[f"segment.{q}.coverage_excited"] = float(np.mean(cov[exc])) if exc.any() else math.nan
        lim = {"J_L": 0.1, "B_L": 0.3, "F_CL": 0.2}[q]
        # the target form: within the limit, or (B_L) flagged not excited
        out[f"segment.{q}.within_or_unexcited"] = float(np.mean((rel <= lim) | ~exc))
    return out


def event_glitches(a: dict[str, F64], events: list[tuple[str, float]]) -> dict[str, float]:
    """At each event: the segment estimate's largest distance from its interval just
    before the event, and the truth's largest distance from the interval, over the 2 s
    after it, both in units of the interval's width just before / at that time. Where
    the parameter itself changed in those 2 s by more than that width (a fresh blank
    clamped near a tool change), moving with it is not counted as a glitch."""
    t = a["t"]
    worst: dict[str, list[float]] = {}
    for kind, te in events:
        k0 = int(np.searchsorted(t, te)) - 1
        if k0 < 1:
            continue
        win = (t >= te) & (t <= te + 2.0)
        for j in range(len(PARAMS)):
            lo0, hi0 = a["lo"][k0, j], a["hi"][k0, j]
            w0 = hi0 - lo0
            est = a["segment"][win, j]
            exc_ = float(np.max(np.maximum(np.maximum(lo0 - est, est - hi0), 0.0))) / w0
            tru = a["truth"][win, j]
            lo, hi = a["lo"][win, j], a["hi"][win, j]
            miss = float(np.max(np.maximum(np.maximum(lo - tru, tru - hi), 0.0) / (hi - lo)))
            if np.max(np.abs(tru - a["truth"][k0, j])) > w0:
                # the parameter itself changed in the window (a fresh blank: J_L; the
                # identifier is told and restarts): following it is no glitch, only the
                # truth against the new interval counts
                exc_ = 0.0
            worst.setdefault(f"{kind}.max_excursion", []).append(exc_)
            worst.setdefault(f"{kind}.max_truth_miss", []).append(miss)
    return {k: float(max(v)) for k, v in worst.items()}


def dfo_recovery(h: F64, events: list[tuple[str, float]], ts: float) -> list[float]:
    """Seconds after each spindle step until both DFO amplitudes are within 5 % of the
    truth and stay so for 0.1 s (nan: not within 2 s)."""
    t = h[:, 0]
    ok = (np.abs(h[:, 1] - h[:, 3]) <= 0.05 * h[:, 3]) & (
        np.abs(h[:, 2] - h[:, 4]) <= 0.05 * h[:, 4]
    )
    hold = int(round(0.1 / ts))
    out = []
    for kind, te in events:
        if kind != "spindle":
            continue
        k = int(np.searchsorted(t, te))
        stop = min(int(np.searchsorted(t, te + 2.0)), len(t) - hold)
        found = math.nan
        for i in range(k, stop):
            if ok[i : i + hold].all():
                found = float(t[i] - te)
                break
        out.append(found)
    return out


def _agg(vals: list[dict[str, float]]) -> dict[str, float]:
    keys = vals[0].keys()
    return {k: float(np.nanmean([v.get(k, math.nan) for v in vals])) for k in keys}


def study(
    minutes: float, seeds: list[int], ablation_minutes: float, progress: bool
) -> tuple[dict[str, dict[str, float]], dict[str, float], list[float], list[dict[str, float]]]:
    """Score every case (default over every seed, each ablation over the first seed)."""
    per_case: dict[str, dict[str, float]] = {}
    per_seed: list[dict[str, float]] = []
    glitches: list[dict[str, float]] = []
    rec: list[float] = []
    for s in seeds:
        tr = run_case(frozenset(), s, minutes, progress=progress)
        a = tr.arrays()
        sc = scores(a)
        per_seed.append(sc)
        glitches.append(event_glitches(a, tr.events))
        rec += dfo_recovery(a["h"], tr.events, 4e-4)
    per_case["default"] = _agg(per_seed)
    for case in CASES[1:]:
        if case == "stepped_wear":
            off = frozenset({"smooth_wear"})
        else:
            off = frozenset(SUSPECTS) if case == "none" else frozenset({case[3:]})
        tr = run_case(off, seeds[0], ablation_minutes, progress=progress)
        per_case[case] = scores(tr.arrays())
    gl: dict[str, float] = {}
    for g in glitches:
        for k, v in g.items():
            gl[k] = max(gl.get(k, 0.0), v)
    return per_case, gl, rec, per_seed


def run(
    *, quick: bool = False, plot_dir: Path | None = None, progress: bool = True
) -> Reproduction:
    minutes, seeds, abl = (2.0, [0, 1], 1.5) if quick else (10.0, [0, 1, 2, 3, 4], 5.0)
    return build(minutes, seeds, abl, progress)


def build(minutes: float, seeds: list[int], abl: float, progress: bool) -> Reproduction:
    per_case, gl, rec, per_seed = study(minutes, seeds, abl, progress)
    rep = Reproduction(NAME, SOURCE)
    cond_d = f"{minutes:g} min after {SKIP:g} s, seeds {seeds[0]}..{seeds[-1]} (mean)"
    cond_a = f"{abl:g} min, seed {seeds[0]}"
    for case, sc in per_case.items():
        cond = cond_d if case == "default" else cond_a
        for k, v in sc.items():
            unit = "" if ("within" in k or "coverage" in k or "excited" in k) else "rel."
            rep.rows.append(Row(f"{case}.{k}", v, None, unit, cond))
    for k, v in sorted(gl.items()):
        rep.rows.append(Row(f"events.{k}", v, None, "widths", cond_d))
    r = np.asarray(rec)
    med = float(np.nanmedian(r)) if np.isfinite(r).any() else math.nan
    worst = float(np.max(np.where(np.isnan(r), np.inf, r))) if len(r) else math.nan
    rep.rows.append(Row("dfo.recovery_time.median", med, None, "s", cond_d))
    rep.rows.append(Row("dfo.recovery_time.max", worst, None, "s", cond_d))
    d = per_case["default"]
    lows = {q: min(s[f"segment.{q}.coverage"] for s in per_seed) for q in PARAMS}
    for q in PARAMS:
        rep.rows.append(Row(f"default.segment.{q}.coverage_worst_seed", lows[q], None, "", cond_d))
    # every seed on its own: one seed is one case
    per_seed_keys = [f"segment.{q}.coverage" for q in PARAMS] + [
        "segment.J_L.within_10",
        "segment.F_CL.within_20",
        "segment.B_L.within_or_unexcited",
        "segment.B_L.within_30",
    ]
    for s, sc in zip(seeds, per_seed, strict=True):
        for k in per_seed_keys:
            rep.rows.append(Row(f"default.seed{s}.{k}", sc[k], None, "", f"{minutes:g} min"))
    # issue 13 item 2's targets (mean over seeds)
    for q in PARAMS:
        rep.checks.append(
            Check(
                f"{q}: 95 % interval covers the truth >= 90 %",
                d[f"segment.{q}.coverage"] >= 0.9,
                d[f"segment.{q}.coverage"],
                0.9,
            )
        )
    rep.checks.append(
        Check(
            "J_L within 10 % >= 80 %",
            d["segment.J_L.within_10"] >= 0.8,
            d["segment.J_L.within_10"],
            0.8,
        )
    )
    rep.checks.append(
        Check(
            "F_CL within 20 % >= 80 %",
            d["segment.F_CL.within_20"] >= 0.8,
            d["segment.F_CL.within_20"],
            0.8,
        )
    )
    rep.checks.append(
        Check(
            "B_L within 30 % or not excited >= 80 %",
            d["segment.B_L.within_or_unexcited"] >= 0.8,
            d["segment.B_L.within_or_unexcited"],
            0.8,
        )
    )
    for k, v in sorted(gl.items()):
        rep.checks.append(Check(f"{k} <= 1 interval width", v <= 1.0, v, 1.0))
    rep.checks.append(
        Check("DFO amplitudes within 5 % in < 0.2 s after a spindle step", worst < 0.2, worst, 0.2)
    )
    return rep


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--minutes", type=float, default=10.0)
    ap.add_argument("--seeds", type=int, default=5)
    ap.add_argument("--ablation-minutes", type=float, default=5.0)
    ap.add_argument("--quick", action="store_true")
    a = ap.parse_args(argv)
    if a.quick:
        rep = run(quick=True)
    else:
        rep = build(a.minutes, list(range(a.seeds)), a.ablation_minutes, True)
    print(format_table(rep))
    return 0 if rep.all_hold else 1


if __name__ == "__main__":
    raise SystemExit(main())
