"""Reproduction of seed 004 (Danai & Ulsoy): Tables 1, 3, 4, wear, and sensorless life.

1. Table 1: the wear model (``machine.tool_wear``) cut for 15 min at f = 0.1 and
   0.125 mm/rev (v = 150 m/min, d = 2 mm), linearised along the path from the origin
   to the 15-min state (appendix, n' = 200), ZOH-discretised (T = 0.01 min), a_i, b_i of
   seed004 (13).
2. Tables 3 and 4: the adaptive observer (RLS with beta = 0.95, U-D, Table 2
   constraints, deadbeat observer) run on the force of the f = 0.1 cut; "true"
   observer-form states ``x0 = T(k)^-1 x(k)`` with T (seed004 (14)) of the model linearised
   at each time. Table 4's mean and S.D. are over its five times, as the paper's are
   (error = true - estimated, sample S.D.).
3. Physical wear: ``x = T x0`` with T of the design linearisation.
4. Beyond the paper: the tool cut pass by pass until VB = 0.3 mm; the tool-life monitor
   fed (a) the pass-mean dynamometer force with noise, (b) the pass-mean force estimated
   by the foundation's adaptive cutting-force observer (seed 000) — its relative error
   over each pass, measured by running the stage and its observer, applied to the true
   turning force (the stage's cutting torque is not the turning force; see the doc).
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass, replace
from pathlib import Path
from typing import TypedDict

import numpy as np

from estimators.wear.monitor import ToolLifeMonitor, ToolLifeParams
from estimators.wear.observer import AdaptiveWearObserver, WearObserverRecord
from harness.wear_clock import (
    SAMPLE_TIME_MIN,
    AcceleratedToolWear,
    DesignModel,
    design_linear_model,
    observer_params,
)
from machine.tool_wear import (
    DEFAULT_WEAR_PARAMS,
    VB_LIMIT_MM,
    CuttingCondition,
    ToolWearModel,
    WearTrajectory,
    crater_limit_mm,
)
from server.experiments.reproduction import Check, Reproduction, Row, Section

NAME = "tool-wear"
SOURCE = "seed 004 (Danai & Ulsoy, Part I) Tables 1, 3, 4; sensorless tool life (issue 7)"

PARAM_NAMES = ("a1", "a2", "a3", "b1", "b2", "b3")
# seed 004 Table 1 (a2 at f = 0.1 is printed 2.9978; with the poles at 1, 1, 0.9889
# that the other five numbers imply it would be 2.9778 — kept as printed)
TABLE1 = {
    0.1: (-2.9889, 2.9978, -0.9889, 15.71587, -31.4317, 15.71586),
    0.125: (-2.9881, 2.9763, -0.9881, 12.8257, -25.6514, 12.8257),
}
TABLE_TIMES = (0.1, 1.0, 4.0, 12.0, 15.0)
# seed 004 Table 3: first line of each time (the linear models), second (estimated)
TABLE3_LIN = {
    0.1: (-2.98, 2.95, -0.98, 14.58, -29.21, 14.63),
    1.0: (-2.98, 2.95, -0.98, 13.78, -27.63, 13.85),
    4.0: (-2.98, 2.95, -0.98, 13.40, -26.88, 13.48),
    12.0: (-2.99, 2.96, -0.98, 15.20, -30.44, 15.24),
    15.0: (-2.98, 2.96, -0.98, 15.70, -31.42, 15.72),
}
TABLE3_EST = {
    0.1: (-3.00, 3.00, -1.00, 14.14, -28.28, 14.14),
    1.0: (-3.00, 2.99, -1.00, 14.14, -28.53, 14.26),
    4.0: (-3.00, 2.99, -1.00, 14.12, -28.54, 14.24),
    12.0: (-3.00, 2.99, -1.00, 14.15, -28.52, 14.27),
    15.0: (-3.00, 2.99, -1.00, 14.16, -28.51, 14.28),
}
# seed 004 Table 4: true and estimated observer-form states
TABLE4_TRUE = {
    0.1: (8.6269, -17.2853, 8.6586),
    1.0: (65.677, -131.750, 66.073),
    4.0: (100.748, -203.481, 102.734),
    12.0: (26.660, -57.505, 30.851),
    15.0: (24.080, -52.172, 28.104),
}
TABLE4_EST = {
    0.1: (4.2419, -8.5839, 4.2420),
    1.0: (62.893, -127.763, 64.806),
    4.0: (100.689, -205.971, 105.277),
    12.0: (26.308, -57.124, 30.829),
    15.0: (23.380, -50.856, 27.504),
}
TABLE4_MEAN = (1.66, -2.38, 0.75)
TABLE4_SD = (1.86, 4.22, 2.51)

FEED = 0.1
#: light -> heavy cutting conditions (f [mm/rev], v [m/min], d [mm]) for section 3
CONDITIONS = {
    "light": (0.1, 150.0, 2.0),
    "medium": (0.15, 180.0, 2.5),
    "heavy": (0.2, 220.0, 3.0),
}
RUN_MIN = 15.0
PASS_MIN = 0.2  # wear minutes per tool pass in the sensorless run
DYNAMOMETER_NOISE_N = 2.0
OVERRUN = 1.1  # cut on past the criterion to see when the alarm comes
STAGE_WARMUP_S = 5.0  # the force observer's identifier settles before the first pass
LIFE_FRACTIONS = (0.25, 0.5, 0.75)
#: sample period of the better-conditioned back-transformation tried [min]
DECIMATED_MIN = 1.0
_P0 = DEFAULT_WEAR_PARAMS
#: model mismatch: the "true" tool's constants differ from the off-line ones the
#: monitor's wear law is built from (tool-to-tool and batch-to-batch variation)
MISMATCH = {
    "scales": {"K1": 0.9 * _P0.K1, "K2": 1.5 * _P0.K2},
    "hotter": {"K3": 1.05 * _P0.K3, "K4": 1.5 * _P0.K4},
    "colder": {"K3": 0.95 * _P0.K3, "K4": 0.6 * _P0.K4},
    "crater_x2": {"K4": 2.0 * _P0.K4},
    "heating_x1.2": {"K7": 1.2 * _P0.K7},
}


def _tname(t: float) -> str:
    return f"t{t:g}min".replace(".", "_")


def _fname(f: float) -> str:
    return f"f{f:.3f}"


ROWS: list[str] = (
    [f"params.{_fname(f)}.{p}" for f in TABLE1 for p in PARAM_NAMES]
    + [
        f"table3.{_tname(t)}.{kind}.{p}"
        for t in TABLE_TIMES
        for kind in ("linear", "est")
        for p in PARAM_NAMES
    ]
    + [
        f"table4.{_tname(t)}.{kind}.x{i}"
        for t in TABLE_TIMES
        for kind in ("true", "est")
        for i in (1, 2, 3)
    ]
    + [f"state_error.{s}.x{i}" for s in ("mean", "sd") for i in (1, 2, 3)]
    + ["table4.true.x1.change_4_to_12min"]
    + [f"state_error.run.{s}.x{i}" for s in ("mean", "sd") for i in (1, 2, 3)]
    + [
        f"model.{c}.{k}"
        for c in ("light", "medium", "heavy")
        for k in ("time_to_vb_min", "time_to_kt_min", "flank_1min_mm", "diffusive_share_at_end")
    ]
    + ["wear.flank.rel_error.15min", "wear.crater.rel_error.15min", "wear.transform.cond"]
    + [
        f"wear.decimated_{DECIMATED_MIN:g}min.{k}"
        for k in ("transform.cond", "flank.rel_error", "crater.rel_error")
    ]
    + [
        "wear.flank.rel_error.dynamometer",
        "wear.flank.rel_error.estimated_force",
        "force_estimate.pass_rel_error.mean",
        "force_estimate.pass_rel_error.sd",
        "life.true_min",
        "life.prediction_error_min",
        "life.prediction_sd_min",
        "life.prediction_error_min.dynamometer",
        "life.warning_at_fraction",
        "life.alarm_at_fraction",
    ]
    + [f"life.{k}.{q}pct" for q in (25, 75) for k in ("prediction_error_min", "prediction_sd_min")]
    + [
        f"life.mismatch.{c}.{k}"
        for c in MISMATCH
        for k in ("true_min", "prediction_error_min", "prediction_sd_min")
    ]
    + ["life.mismatch.max_abs_error_in_sd"]
)


def _table1(model: ToolWearModel, feed: float) -> tuple[np.ndarray, np.ndarray]:
    n = round(RUN_MIN / SAMPLE_TIME_MIN)
    tr = model.simulate(np.full(n, feed), SAMPLE_TIME_MIN)
    dm = design_linear_model(model, feed, tr.states[-1])
    return dm.a, dm.b


def _force_observer_errors(n_passes: int, pass_seconds: float, seed: int) -> np.ndarray:
    """Relative error of the pass mean of the foundation's adaptive force estimate."""
    from server.pipeline.stage_run import StageRun

    run = StageRun(seed=seed)
    n = round(pass_seconds / run.sim.config.sample_time)
    # the stage and its identifier run before the cut starts (warm-up)
    run.step(round(STAGE_WARMUP_S / run.sim.config.sample_time))
    errs = np.empty(n_passes)
    for j in range(n_passes):
        blk = run.step(n)
        errs[j] = float(np.mean(blk.f_adaptive) / np.mean(blk.f_true) - 1.0)
    return errs


class LifeRun(TypedDict):
    """One tool cut to its life (:func:`_life_run`): per pass the time [min], true VB and
    crater, force; the true life [min]; the monitor's records fed the dynamometer's and
    the estimated force (``vb``, ``vb_trend``, ``remaining_life``, its sd, ``warning``,
    ``alarm``); the monitor's parameters."""

    t: np.ndarray
    vb: np.ndarray
    crater: np.ndarray
    F: np.ndarray
    life: float
    dyn: dict[str, np.ndarray]
    est: dict[str, np.ndarray]
    params: ToolLifeParams


def _life_run(force_errors: np.ndarray, rng: np.random.Generator) -> LifeRun:
    """Cut passes until VB = 0.3 mm; monitor fed dynamometer and estimated force."""
    true_w = AcceleratedToolWear(feed=FEED, wear_minutes_per_second=1.0)
    mon = ToolLifeMonitor(true_w.monitor.params)
    st_dyn = st_est = mon.initial_state()
    t, vb_true, crater, F = [], [], [], []
    recs_dyn, recs_est = [], []
    j = 0
    while True:
        tw, Fm, x = true_w.cut_pass(PASS_MIN)
        f_dyn = Fm + DYNAMOMETER_NOISE_N * rng.standard_normal()
        st_dyn, r_dyn = mon.step(st_dyn, [tw], [f_dyn], [FEED])
        recs_dyn.append(r_dyn)
        f_est = Fm * (1.0 + force_errors[j % len(force_errors)])
        st_est, r_est = mon.step(st_est, [tw], [f_est], [FEED])
        recs_est.append(r_est)
        t.append(tw)
        vb_true.append(x[0] + x[1])
        crater.append(x[2])
        F.append(Fm)
        j += 1
        if vb_true[-1] >= OVERRUN * VB_LIMIT_MM or j > 2000:
            break
    ta = np.array(t)
    vb = np.array(vb_true)
    # true tool life: linear interpolation of the crossing
    life = float(np.interp(VB_LIMIT_MM, vb, ta))

    def cat(recs: list) -> dict[str, np.ndarray]:
        keys = ("vb", "vb_trend", "remaining_life", "remaining_life_sd", "warning", "alarm")
        return {k: np.concatenate([getattr(r, k) for r in recs]) for k in keys}

    return {
        "t": ta,
        "vb": vb,
        "crater": np.array(crater),
        "F": np.array(F),
        "life": life,
        "dyn": cat(recs_dyn),
        "est": cat(recs_est),
        "params": mon.params,
    }


def _decimated_wear(model: ToolWearModel, tr: object) -> tuple[float, float, float, float]:
    """x = T x0 on a decimated clock, with the exact a, b and T of the current state.

    The best case for seed004 (14): no RLS error (the design model's parameters, re-linearised
    at every decimated sample) and a sample period of :data:`DECIMATED_MIN`, where T is
    far better conditioned. Returns cond(T) at the end, the flank and crater relative
    errors at the last decimated sample, and its time [min].
    """
    from estimators.wear.observer import deadbeat_observer_step

    states = np.asarray(tr.states)  # type: ignore[attr-defined]
    force = np.asarray(tr.force)  # type: ignore[attr-defined]
    step = round(DECIMATED_MIN / SAMPLE_TIME_MIN)
    d_static = model.force(np.zeros(3), FEED) / FEED
    x0 = np.zeros(3)
    x_hat = np.zeros(3)
    cond, k_last = 0.0, 0
    for k in range(0, len(force), step):
        dm = design_linear_model(model, FEED, states[max(k, 1)], sample_time=DECIMATED_MIN)
        # seed004 (14): the estimate of x(k) from the observer-form state before the update
        x_hat = dm.T @ x0
        cond, k_last = float(np.linalg.cond(dm.T)), k
        # seed004 (17)-(19) with the design model's a, b (deadbeat)
        x0 = deadbeat_observer_step(dm.a, dm.b, x0, FEED, float(force[k] - d_static * FEED))
    xt = states[k_last]
    wf = xt[0] + xt[1]
    return (
        cond,
        float((x_hat[0] + x_hat[1] - wf) / wf),
        float((x_hat[2] - xt[2]) / xt[2]),
        k_last * SAMPLE_TIME_MIN,
    )


def _mismatch_run(
    true_params: dict[str, float], mon: ToolLifeMonitor
) -> tuple[float, list[tuple[float, float]]]:
    """A tool with other constants than the monitor's; dynamometer force without noise.

    Returns the true life [min] and (prediction error, predicted S.D.) [min] at each of
    :data:`LIFE_FRACTIONS` of it.
    """
    m = ToolWearModel(params=replace(DEFAULT_WEAR_PARAMS, **true_params))
    st = mon.initial_state()
    x = np.zeros(3)
    tw = 0.0
    t, vb, rul, sd = [], [], [], []
    while True:
        tr = m.simulate(np.full(20, FEED), PASS_MIN / 20, x0=x)
        x = tr.states[-1]
        tw += PASS_MIN
        st, r = mon.step(st, [tw], [float(np.mean(tr.force))], [FEED])
        t.append(tw)
        vb.append(x[0] + x[1])
        rul.append(float(r.remaining_life[0]))
        sd.append(float(r.remaining_life_sd[0]))
        if vb[-1] >= VB_LIMIT_MM or len(t) > 2000:
            break
    ta = np.array(t)
    life = float(np.interp(VB_LIMIT_MM, np.array(vb), ta))
    out = []
    for fr in LIFE_FRACTIONS:
        j = int(np.searchsorted(ta, fr * life))
        out.append((rul[j] - (life - ta[j]), sd[j]))
    return life, out


def section3_behaviour() -> dict[str, dict[str, float]]:
    """Times to VB = 0.3 mm and to the ISO crater limit, wear shares, at 3 conditions."""
    out: dict[str, dict[str, float]] = {}
    for name, (f, v, d) in CONDITIONS.items():
        m = ToolWearModel(condition=CuttingCondition(speed=v, depth=d))
        n = round(60.0 / SAMPLE_TIME_MIN)
        tr = m.simulate(np.full(n, f), SAMPLE_TIME_MIN)
        x = tr.states[:-1]
        vb = x[:, 0] + x[:, 1]
        kt_lim = crater_limit_mm(f)
        t_vb = float(tr.t[np.argmax(vb >= VB_LIMIT_MM)]) if np.any(vb >= VB_LIMIT_MM) else np.inf
        t_kt = float(tr.t[np.argmax(x[:, 2] >= kt_lim)]) if np.any(x[:, 2] >= kt_lim) else np.inf
        k1 = round(1.0 / SAMPLE_TIME_MIN)
        k5 = round(5.0 / SAMPLE_TIME_MIN)
        out[name] = {
            "diffusive_share_5min": float(x[k5, 1] / vb[k5]),
            "t_vb": t_vb,
            "t_kt": t_kt,
            "flank_1min": float(vb[k1]),
            "diffusive_share_end": float(
                x[round(min(t_vb, t_kt) / SAMPLE_TIME_MIN) - 1, 1]
                / vb[round(min(t_vb, t_kt) / SAMPLE_TIME_MIN) - 1]
            ),
        }
    return out


def rows_section3() -> Section:
    """Section 3: qualitative behaviour under light -> heavy cutting."""
    rows: list[Row] = []
    checks: list[Check] = []
    beh = section3_behaviour()
    for name, vals in beh.items():
        f, v, d = CONDITIONS[name]
        cond = f"f={f:g}, v={v:g}, d={d:g}"
        rows.append(
            Row(
                f"model.{name}.time_to_vb_min",
                vals["t_vb"],
                None,
                "min",
                f"{cond}: flank VB = 0.3 mm",
            )
        )
        rows.append(
            Row(
                f"model.{name}.time_to_kt_min",
                vals["t_kt"],
                None,
                "min",
                f"{cond}: crater KT = 0.06 + 0.3 f mm (ISO 3685)",
            )
        )
        rows.append(
            Row(
                f"model.{name}.flank_1min_mm",
                vals["flank_1min"],
                None,
                "mm",
                f"{cond}: flank wear after 1 min",
            )
        )
        rows.append(
            Row(
                f"model.{name}.diffusive_share_5min",
                vals["diffusive_share_5min"],
                None,
                "-",
                f"{cond}: w_f2 / w_f after 5 min of cutting",
            )
        )
        rows.append(
            Row(
                f"model.{name}.diffusive_share_at_end",
                vals["diffusive_share_end"],
                None,
                "-",
                f"{cond}: w_f2 / w_f at the end of tool life",
            )
        )
    names = list(CONDITIONS)
    grows = all(beh[a]["flank_1min"] < beh[b]["flank_1min"] for a, b in itertools.pairwise(names))
    checks.append(
        Check(
            "section 3 (i): wear grows faster under heavier cutting",
            grows,
            beh[names[-1]]["flank_1min"],
            beh[names[0]]["flank_1min"],
        )
    )
    heavy = beh[names[-1]]
    light = beh[names[0]]
    checks.append(
        Check(
            "section 3 (ii): diffusive part dominates flank wear at heavy (5 min)",
            heavy["diffusive_share_5min"] > max(light["diffusive_share_5min"], 0.5),
            heavy["diffusive_share_5min"],
            0.5,
        )
    )
    checks.append(
        Check(
            "section 3 (iii): crater ends the tool at heavy, flank at light",
            heavy["t_kt"] < heavy["t_vb"] and light["t_vb"] < light["t_kt"],
            heavy["t_kt"],
            heavy["t_vb"],
        )
    )
    return rows, checks


def _rel_rms(est: np.ndarray, true: np.ndarray, mask: np.ndarray) -> float:
    return float(np.sqrt(np.mean(((est[mask] - true[mask]) / true[mask]) ** 2)))


@dataclass(frozen=True)
class _ObserverRun:
    """The adaptive observer on the force of the f = 0.1 cut (Tables 3, 4)."""

    model: ToolWearModel
    n: int
    tr: WearTrajectory
    rec: WearObserverRecord
    end_design: DesignModel

    def true_x0(self, k: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """True observer-form state ``x0 = T(k)^-1 x(k)`` and a, b of the model
        linearised at sample ``k``."""
        dm = design_linear_model(self.model, FEED, self.tr.states[k])
        return np.linalg.solve(dm.T, self.tr.states[k]), dm.a, dm.b


def observer_run(model: ToolWearModel) -> _ObserverRun:
    n = round(RUN_MIN / SAMPLE_TIME_MIN)
    tr = model.simulate(np.full(n, FEED), SAMPLE_TIME_MIN)
    end_design = design_linear_model(model, FEED, tr.states[-1])
    obs = AdaptiveWearObserver(observer_params(transform=end_design.T))
    _, rec = obs.step(obs.initial_state(), tr.force, tr.feed)
    return _ObserverRun(model, n, tr, rec, end_design)


def rows_table1(model: ToolWearModel) -> Section:
    """Table 1: a_i, b_i of the linearised model at both feeds."""
    rows: list[Row] = []
    checks: list[Check] = []
    worst = 0.0
    for f, paper in TABLE1.items():
        a, b = _table1(model, f)
        for name, ours, pv in zip(PARAM_NAMES, (*a, *b), paper):
            rows.append(
                Row(
                    f"params.{_fname(f)}.{name}",
                    float(ours),
                    pv,
                    "-",
                    f"f={f:g} mm/rev, v=150 m/min, d=2 mm, 15 min, n'=200",
                )
            )
            worst = max(worst, abs(ours - pv) / abs(pv))
    checks.append(Check("table1 parameters within 1 % of the paper's", worst <= 0.01, worst, 0.01))

    return rows, checks


def rows_tables34(run: _ObserverRun) -> Section:
    """Tables 3 and 4 at their five times, and Table 4's error statistics."""
    rows: list[Row] = []
    checks: list[Check] = []
    rec = run.rec
    true_x0 = run.true_x0
    errs = []
    x01_true: dict[float, float] = {}
    for tm in TABLE_TIMES:
        k = round(tm / SAMPLE_TIME_MIN) - 1
        x0, a, b = true_x0(k)
        tn = _tname(tm)
        for name, ours, pv in zip(PARAM_NAMES, (*a, *b), TABLE3_LIN[tm]):
            rows.append(
                Row(
                    f"table3.{tn}.linear.{name}",
                    float(ours),
                    pv,
                    "-",
                    "model linearised at this time",
                )
            )
        for name, ours, pv in zip(PARAM_NAMES, rec.theta[k], TABLE3_EST[tm]):
            rows.append(
                Row(
                    f"table3.{tn}.est.{name}",
                    float(ours),
                    pv,
                    "-",
                    "RLS beta=0.95, U-D, Table 2 constraints",
                )
            )
        for i in range(3):
            rows.append(
                Row(
                    f"table4.{tn}.true.x{i + 1}",
                    float(x0[i]),
                    TABLE4_TRUE[tm][i],
                    "N",
                    "x0 = T^-1 x",
                )
            )
            rows.append(
                Row(
                    f"table4.{tn}.est.x{i + 1}",
                    float(rec.x0_hat[k, i]),
                    TABLE4_EST[tm][i],
                    "N",
                    "deadbeat observer eq. (17)",
                )
            )
        errs.append(x0 - rec.x0_hat[k])
        x01_true[tm] = float(x0[0])
    # seed004 (16): x01 = y - D u, the wear part of the force. Table 4's true x01 falls from
    # 100.7 N at 4 min to 26.7 N at 12 min: the paper's force is not monotone in time
    # while the wear grows, so it cannot be a monotone function of the flank wear.
    rows.append(
        Row(
            "table4.true.x1.change_4_to_12min",
            x01_true[12.0] - x01_true[4.0],
            TABLE4_TRUE[12.0][0] - TABLE4_TRUE[4.0][0],
            "N",
            "x01 = F - D f (eq. 16): change of the wear force from 4 to 12 min",
        )
    )
    E = np.array(errs)
    mean, sd = E.mean(axis=0), E.std(axis=0, ddof=1)
    for i in range(3):
        rows.append(
            Row(
                f"state_error.mean.x{i + 1}",
                float(mean[i]),
                TABLE4_MEAN[i],
                "N",
                "true - estimated, over Table 4's five times",
            )
        )
    for i in range(3):
        rows.append(
            Row(
                f"state_error.sd.x{i + 1}",
                float(sd[i]),
                TABLE4_SD[i],
                "N",
                "sample S.D. over Table 4's five times",
            )
        )
    for i in range(3):
        checks.append(
            Check(
                f"state_error.mean.x{i + 1} within twice Table 4's",
                abs(mean[i]) <= 2 * abs(TABLE4_MEAN[i]),
                abs(float(mean[i])),
                2 * abs(TABLE4_MEAN[i]),
            )
        )
    for i in range(3):
        checks.append(
            Check(
                f"state_error.sd.x{i + 1} within twice Table 4's",
                sd[i] <= 2 * TABLE4_SD[i],
                float(sd[i]),
                2 * TABLE4_SD[i],
            )
        )

    return rows, checks


def run_states(run: _ObserverRun, stride: int) -> tuple[np.ndarray, np.ndarray]:
    """Sample indices every ``stride`` samples and the true x0 there."""
    ks = np.arange(stride - 1, run.n, stride)
    x0_run = np.array([run.true_x0(int(k))[0] for k in ks])
    return ks, x0_run


def rows_state_error_run(
    run: _ObserverRun, stride: int, ks: np.ndarray, x0_run: np.ndarray
) -> Section:
    """Table 4's statistics over the whole run (not in the paper), every ``stride``
    samples."""
    rows: list[Row] = []
    E_run = x0_run - run.rec.x0_hat[ks]
    for s, vals in (("mean", E_run.mean(axis=0)), ("sd", E_run.std(axis=0, ddof=1))):
        for i in range(3):
            rows.append(
                Row(
                    f"state_error.run.{s}.x{i + 1}",
                    float(vals[i]),
                    None,
                    "N",
                    f"every {stride} samples over 15 min",
                )
            )

    return rows, []


def rows_wear(run: _ObserverRun) -> Section:
    """Physical wear: ``x = T x0``."""
    rows: list[Row] = []
    rec, tr, n, end_design, model = run.rec, run.tr, run.n, run.end_design, run.model
    assert rec.wear is not None
    k15 = n - 1
    wf_true = tr.states[k15, 0] + tr.states[k15, 1]
    wc_true = tr.states[k15, 2]
    wf_est = rec.wear[k15, 0] + rec.wear[k15, 1]
    wc_est = rec.wear[k15, 2]
    rows.append(
        Row(
            "wear.flank.rel_error.15min",
            float((wf_est - wf_true) / wf_true),
            None,
            "-",
            "x = T x0, T of the design linearisation (eq. 14)",
        )
    )
    rows.append(
        Row(
            "wear.crater.rel_error.15min",
            float((wc_est - wc_true) / wc_true),
            None,
            "-",
            "x = T x0",
        )
    )
    rows.append(
        Row(
            "wear.transform.cond",
            float(np.linalg.cond(end_design.T)),
            None,
            "-",
            "condition number of T",
        )
    )
    cond_d, rel_f, rel_c, t_d = _decimated_wear(model, tr)
    cond_txt = f"exact a, b, T re-linearised each sample, T = {DECIMATED_MIN:g} min"
    for key, val in (
        ("transform.cond", cond_d),
        ("flank.rel_error", rel_f),
        ("crater.rel_error", rel_c),
    ):
        rows.append(
            Row(
                f"wear.decimated_{DECIMATED_MIN:g}min.{key}",
                val,
                None,
                "-",
                f"{cond_txt}; at t = {t_d:g} min",
            )
        )

    return rows, []


def rows_life(life: LifeRun, ferr: np.ndarray, pass_seconds: float) -> Section:
    """Beyond the paper: sensorless tool life, dynamometer and estimated force."""
    rows: list[Row] = []
    checks: list[Check] = []
    t = np.asarray(life["t"])
    vb = np.asarray(life["vb"])
    life_min = float(life["life"])
    dyn, est = life["dyn"], life["est"]
    mask = (t >= 2.0) & (vb <= VB_LIMIT_MM)
    rel_dyn = _rel_rms(dyn["vb"], vb, mask)
    rel_est = _rel_rms(est["vb"], vb, mask)
    rows.append(
        Row(
            "wear.flank.rel_error.dynamometer",
            rel_dyn,
            None,
            "-",
            f"rms of (VB_hat - VB)/VB per pass, 2 min..end of life, "
            f"{DYNAMOMETER_NOISE_N:g} N noise",
        )
    )
    rows.append(
        Row(
            "wear.flank.rel_error.estimated_force",
            rel_est,
            None,
            "-",
            "same, pass-mean force from the seed-000 adaptive observer",
        )
    )
    rows.append(
        Row(
            "force_estimate.pass_rel_error.mean",
            float(np.mean(ferr)),
            None,
            "-",
            f"{pass_seconds:g} s passes of the stage at 2.5 kHz",
        )
    )
    rows.append(
        Row("force_estimate.pass_rel_error.sd", float(np.std(ferr)), None, "-", "over passes")
    )
    rows.append(
        Row(
            "life.true_min", life_min, None, "min", f"VB = {VB_LIMIT_MM} mm at f={FEED}, v=150, d=2"
        )
    )
    j50 = int(np.searchsorted(t, 0.5 * life_min))
    true_rul = life_min - t[j50]
    for key, recd in (("", est), (".dynamometer", dyn)):
        err = float(recd["remaining_life"][j50] - true_rul)
        rows.append(
            Row(
                f"life.prediction_error_min{key}",
                err,
                None,
                "min",
                f"predicted - true remaining life at t = {t[j50]:.1f} min (50 % of life)",
            )
        )
        if key == "":
            rows.append(
                Row(
                    "life.prediction_sd_min",
                    float(recd["remaining_life_sd"][j50]),
                    None,
                    "min",
                    "predicted S.D. (1 sigma) at 50 % of life",
                )
            )
    for flag in ("warning", "alarm"):
        hit = np.flatnonzero(est[flag])
        at = float(t[hit[0]] / life_min) if len(hit) else float("nan")
        rows.append(
            Row(
                f"life.{flag}_at_fraction",
                at,
                None,
                "-",
                "first flag time / true tool life (estimated force)",
            )
        )
    for q in (25, 75):
        jq = int(np.searchsorted(t, q / 100 * life_min))
        rows.append(
            Row(
                f"life.prediction_error_min.{q}pct",
                float(est["remaining_life"][jq] - (life_min - t[jq])),
                None,
                "min",
                f"predicted - true remaining life at t = {t[jq]:.1f} min ({q} % of life)",
            )
        )
        rows.append(
            Row(
                f"life.prediction_sd_min.{q}pct",
                float(est["remaining_life_sd"][jq]),
                None,
                "min",
                f"predicted S.D. (1 sigma) at {q} % of life",
            )
        )
    k50_ok = abs(float(est["remaining_life"][j50]) - true_rul)
    checks.append(
        Check(
            "remaining life at 50 % of life within 3 sigma",
            k50_ok <= 3 * float(est["remaining_life_sd"][j50]),
            k50_ok,
            3 * float(est["remaining_life_sd"][j50]),
        )
    )

    return rows, checks


def rows_mismatch(life: LifeRun) -> Section:
    """Remaining life of tools whose wear constants differ from the monitor's."""
    rows: list[Row] = []
    checks: list[Check] = []
    mon_params = life["params"]
    worst_sigma = 0.0
    for case, kw in MISMATCH.items():
        # the monitor keeps the nominal constants (off-line knowledge)
        life_c, pts = _mismatch_run(kw, ToolLifeMonitor(mon_params))
        desc = ", ".join(f"{k} x{v / getattr(DEFAULT_WEAR_PARAMS, k):g}" for k, v in kw.items())
        e50, s50 = pts[LIFE_FRACTIONS.index(0.5)]
        rows.append(Row(f"life.mismatch.{case}.true_min", life_c, None, "min", desc))
        rows.append(
            Row(
                f"life.mismatch.{case}.prediction_error_min",
                e50,
                None,
                "min",
                f"{desc}; at 50 % of life, dynamometer without noise",
            )
        )
        rows.append(
            Row(f"life.mismatch.{case}.prediction_sd_min", s50, None, "min", "1 sigma at 50 %")
        )
        worst_sigma = max([worst_sigma] + [abs(e) / sd for e, sd in pts])
    rows.append(
        Row(
            "life.mismatch.max_abs_error_in_sd",
            worst_sigma,
            None,
            "-",
            f"max |error| / S.D. over {len(MISMATCH)} mismatched tools at 25, 50, 75 % of life",
        )
    )
    checks.append(
        Check(
            "remaining life of mismatched tools within 3 sigma (25, 50, 75 % of life)",
            worst_sigma <= 3.0,
            worst_sigma,
            3.0,
        )
    )

    return rows, checks


def run(
    *, quick: bool = False, plot_dir: Path | None = None, progress: bool = True
) -> Reproduction:
    """Run the reproduction (``quick`` evaluates the run-long statistics more sparsely)."""
    rep = Reproduction(experiment=NAME, source=SOURCE)
    model = ToolWearModel()
    rep.add(rows_table1(model))
    rep.add(rows_section3())
    obs = observer_run(model)
    rep.add(rows_tables34(obs))
    stride = 50 if quick else 10
    ks, x0_run = run_states(obs, stride)
    rep.add(rows_state_error_run(obs, stride, ks, x0_run))
    rep.add(rows_wear(obs))
    pass_seconds = PASS_MIN  # at one minute of wear per second
    ferr = _force_observer_errors(40 if quick else 200, pass_seconds, seed=1)
    life = _life_run(ferr, np.random.default_rng(7))
    life_rows, life_checks = rows_life(life, ferr, pass_seconds)
    mismatch_rows, mismatch_checks = rows_mismatch(life)
    # rows: life then mismatch; checks: the mismatch check first (the order of before)
    rep.add((life_rows + mismatch_rows, mismatch_checks + life_checks))
    if plot_dir is not None:
        rep.figures.extend(_plots(Path(plot_dir), obs.tr, obs.rec, ks, x0_run, life))
    return rep


def _plots(
    out: Path, tr: object, rec: object, ks: np.ndarray, x0_run: np.ndarray, life: LifeRun
) -> list[str]:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    out.mkdir(parents=True, exist_ok=True)
    files = []
    t = np.asarray(tr.t)  # type: ignore[attr-defined]
    states = np.asarray(tr.states)  # type: ignore[attr-defined]
    x0h = np.asarray(rec.x0_hat)  # type: ignore[attr-defined]
    wear = np.asarray(rec.wear)  # type: ignore[attr-defined]
    fig, axs = plt.subplots(3, 1, figsize=(8, 8), sharex=True)
    for i, ax in enumerate(axs):
        ax.plot(t[ks], x0_run[:, i], "k-", label="true (T^-1 x)")
        ax.plot(t, x0h[:, i], "r--", lw=1, label="estimated")
        ax.set_ylabel(f"x0{i + 1} [N]")
    axs[0].legend()
    axs[-1].set_xlabel("time [min]")
    fig.suptitle("seed 004 Table 4: observer-form states, f = 0.1 mm/rev")
    p = out / "tool_wear_states.png"
    fig.savefig(p, dpi=100)
    plt.close(fig)
    files.append(str(p))

    fig, axs = plt.subplots(2, 1, figsize=(8, 6), sharex=True)
    axs[0].plot(t, states[:-1, 0] + states[:-1, 1], "k-", label="true flank w_f")
    axs[0].plot(t, states[:-1, 0], "b:", label="abrasive w_f1")
    axs[0].plot(t, states[:-1, 1], "g:", label="diffusive w_f2")
    axs[0].plot(t, states[:-1, 2], "m-", label="crater w_c")
    axs[0].set_ylabel("wear [mm]")
    axs[0].legend()
    axs[1].plot(t, wear[:, 0] + wear[:, 1], "r-", label="flank, x = T x0")
    axs[1].plot(t, wear[:, 2], "m--", label="crater, x = T x0")
    axs[1].plot(t, states[:-1, 0] + states[:-1, 1], "k-", lw=1, label="true flank")
    axs[1].set_yscale("symlog", linthresh=0.1)
    axs[1].set_ylabel("back-transformed [mm] (symlog)")
    axs[1].set_xlabel("time [min]")
    axs[1].legend()
    p = out / "tool_wear_physical.png"
    fig.savefig(p, dpi=100)
    plt.close(fig)
    files.append(str(p))

    tl = np.asarray(life["t"])
    est = life["est"]
    dyn = life["dyn"]
    fig, axs = plt.subplots(2, 1, figsize=(8, 7), sharex=True)
    axs[0].plot(tl, np.asarray(life["vb"]), "k-", label="true VB")
    axs[0].plot(tl, dyn["vb"], ".", ms=2, label="dynamometer")
    axs[0].plot(tl, est["vb"], ".", ms=2, label="estimated force")
    axs[0].plot(tl, est["vb_trend"], "r-", lw=1, label="trend (estimated force)")
    axs[0].axhline(VB_LIMIT_MM, color="grey", ls="--")
    axs[0].set_ylabel("flank wear VB [mm]")
    axs[0].legend()
    life_min = float(life["life"])
    axs[1].plot(tl, np.maximum(life_min - tl, 0), "k-", label="true remaining life")
    rul = est["remaining_life"]
    sd = est["remaining_life_sd"]
    axs[1].plot(tl, rul, "r-", label="predicted")
    axs[1].fill_between(tl, rul - 2 * sd, rul + 2 * sd, color="r", alpha=0.2, label="2 sigma")
    axs[1].set_ylim(0, 2 * life_min)
    axs[1].set_ylabel("remaining life [min]")
    axs[1].set_xlabel("cutting time [min]")
    axs[1].legend()
    p = out / "tool_wear_life.png"
    fig.savefig(p, dpi=100)
    plt.close(fig)
    files.append(str(p))
    return files
