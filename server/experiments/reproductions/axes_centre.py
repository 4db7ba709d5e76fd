"""The axes' process force on the machining centre's 500 Hz trace (issue 31 item 2).

The live pipeline of scenario ``machining-centre`` (the CNC's trace at 500 Hz, point
samples) per seed; its ``axes`` part's process force ``<axis>.F`` (the effort less the
rigid model identified live) and its ``two_inertia`` part's ``X.F_2i`` (seed 000's
observer from the parameters identified on the trace) against the simulator's truth
(the cycle's mean force on the workpiece along the axis), after the first 30 s: the rms
error beside the force's own rms; X's identified stiffness, masses and mode beside the
simulated machine's (:class:`machine.centre.params.CentreParams`).
"""

from __future__ import annotations

from pathlib import Path
from typing import NamedTuple

import numpy as np

from server.experiments.reproduction import Check, Reproduction, Row

NAME = "axes-centre"
SOURCE = "issue 31 item 2; the machining centre (docs/machining-centre.md), its 500 Hz trace"
ROWS = [
    "<X|Y|Z>.<force_rms|F_err_rms|F_err_share>",
    "X.<F_2i_err_rms|F_2i_over_F|K|M_M|M_L|mode_hz> (paper: the simulated machine's)",
]
RATE = 500.0
SKIP = 30.0
BLOCK = 25


Series = tuple[dict[str, np.ndarray], dict[str, np.ndarray]]


class CaseRun(NamedTuple):
    """One seed's run: the scores by row name (``X.F_err_rms``, ``X.K``, ...) and the
    series (the outputs, the truth) for the figure."""

    scores: dict[str, float]
    series: Series


def run_case(seed: int, seconds: float) -> CaseRun:
    """One seed: the scored errors and X's identified parameters at the end; the last
    run's series for the figure."""
    from server.pipeline.centre_source import CentreSource
    from server.pipeline.live_pipeline import LivePipeline

    p = LivePipeline("machining-centre", seed=seed)
    src = p.source
    assert isinstance(src, CentreSource)
    keep = ("X.F", "X.F_2i", "Y.F", "Z.F", "X.K", "X.M_M", "X.M_L", "X.mode_hz")
    outs: dict[str, list[np.ndarray]] = {k: [] for k in keep}
    truth: dict[str, list[np.ndarray]] = {f"true_{a}_f_process": [] for a in "XYZ"}
    for _ in range(int(round(seconds * RATE / BLOCK))):
        o = p.step(BLOCK)
        for k in keep:
            outs[k].append(o[k])
        for k in truth:
            truth[k].append(src.truth[k])
    o = {k: np.concatenate(v) for k, v in outs.items()}
    t = {k: np.concatenate(v) for k, v in truth.items()}
    m = np.arange(len(o["X.F"])) >= SKIP * RATE
    res: dict[str, float] = {}
    for a in "XYZ":
        tru = t[f"true_{a}_f_process"][m]
        res[f"{a}.force_rms"] = float(np.sqrt(np.mean(tru**2)))
        res[f"{a}.F_err_rms"] = float(np.sqrt(np.nanmean((o[f"{a}.F"][m] - tru) ** 2)))
    tx = t["true_X_f_process"][m]
    res["X.F_2i_err_rms"] = float(np.sqrt(np.nanmean((o["X.F_2i"][m] - tx) ** 2)))
    for k in ("K", "M_M", "M_L", "mode_hz"):
        res[f"X.{k}"] = float(o[f"X.{k}"][-1])
    return CaseRun(res, (o, t))


def run(
    *, quick: bool = False, plot_dir: Path | None = None, progress: bool = True
) -> Reproduction:
    """``quick``: 1 seed x 60 s; else 6 seeds x 120 s."""
    from tqdm import tqdm

    from machine.centre.params import CentreParams

    seeds, seconds = ([3], 60.0) if quick else (list(range(6)), 120.0)
    runs = []
    for seed in tqdm(seeds, desc=NAME, disable=not progress, leave=False):
        runs.append(run_case(seed, seconds))
    cond = f"{len(seeds)} seed(s) x {seconds:g} s at 500 Hz, scored after {SKIP:g} s"
    x = CentreParams().axes[0]
    truth = {"K": x.stiffness, "M_M": x.motor_mass, "M_L": x.load(0.65)}
    rep = Reproduction(NAME, SOURCE)

    def mean(k: str) -> float:
        return float(np.mean([r.scores[k] for r in runs]))

    def worst(k: str) -> float:
        return float(np.max([r.scores[k] for r in runs]))

    for a in "XYZ":
        rep.rows += [
            Row(f"{a}.force_rms", mean(f"{a}.force_rms"), None, "N", cond),
            Row(f"{a}.F_err_rms", mean(f"{a}.F_err_rms"), None, "N", "rigid model, vs the truth"),
            Row(f"{a}.F_err_share", mean(f"{a}.F_err_rms") / mean(f"{a}.force_rms"), None, "",
                "the error over the force's rms"),
        ]  # fmt: skip
    ratio = mean("X.F_2i_err_rms") / mean("X.F_err_rms")
    rep.rows += [
        Row("X.F_2i_err_rms", mean("X.F_2i_err_rms"), None, "N", "two-inertia observer"),
        Row("X.F_2i_over_F", ratio, None, "", "two-inertia error over the rigid model's"),
        Row("X.K", mean("X.K") / 1e6, truth["K"] / 1e6, "N/um", "identified on the trace"),
        Row("X.M_M", mean("X.M_M"), truth["M_M"], "kg", "identified on the trace"),
        Row("X.M_L", mean("X.M_L"), truth["M_L"], "kg", "identified on the trace"),
        Row("X.mode_hz", mean("X.mode_hz"), 130.0, "Hz", "from K, M_M, M_L"),
    ]
    for a in "XY":
        share = max(r.scores[f"{a}.F_err_rms"] / r.scores[f"{a}.force_rms"] for r in runs)
        rep.checks.append(Check(f"{a}.F_err_under_half_the_force", share < 0.5, share, 0.5))
    rep.checks += [
        Check("Z.F_err_under_60N", worst("Z.F_err_rms") < 60.0, worst("Z.F_err_rms"), 60.0),
        Check("X.two_inertia_beats_rigid", ratio < 0.85, ratio, 0.85),
        Check("X.K_within_3pct", abs(mean("X.K") / truth["K"] - 1) < 0.03,
              mean("X.K") / truth["K"], 1.0),
    ]  # fmt: skip
    if plot_dir is not None:
        _plot(runs[-1].series, plot_dir)
    return rep


def _plot(series: Series, plot_dir: Path) -> None:
    """X's process force in T2's side cuts (N140, N150): the truth, the rigid model's and
    the two-inertia observer's, and Y's beside its truth."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    o, t = series
    time = np.arange(len(o["X.F"])) / RATE
    w = (time >= 40.0) & (time <= 56.0)
    fig, axs = plt.subplots(2, 1, figsize=(10, 6), sharex=True)
    axs[0].plot(time[w], t["true_X_f_process"][w], color="#000000", lw=1.0, label="truth")
    axs[0].plot(time[w], o["X.F"][w], color="#1e88e5", lw=1.0, label="rigid model (X.F)")
    axs[0].plot(time[w], o["X.F_2i"][w], color="#d81b60", lw=1.0,
                label="two-inertia observer (X.F_2i)")  # fmt: skip
    axs[0].set_ylabel("X force [N]")
    axs[0].legend(loc="upper right", fontsize=8)
    axs[1].plot(time[w], t["true_Y_f_process"][w], color="#000000", lw=1.0, label="truth")
    axs[1].plot(time[w], o["Y.F"][w], color="#1e88e5", lw=1.0, label="rigid model (Y.F)")
    axs[1].set_ylabel("Y force [N]")
    axs[1].set_xlabel("time [s] (machining centre, 500 Hz trace)")
    axs[1].legend(loc="upper right", fontsize=8)
    fig.suptitle("The axes' process force on the machining centre's 500 Hz trace")
    fig.tight_layout()
    plot_dir.mkdir(parents=True, exist_ok=True)
    fig.savefig(plot_dir / "centre-axis-force.png", dpi=110)
    plt.close(fig)
