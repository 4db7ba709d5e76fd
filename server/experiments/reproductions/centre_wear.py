"""Wear per tool on the machining centre (issue 31 item 2, issue 35 item 7): the live part's
estimate against the simulator's truth VB, over seeds.

Not a paper's experiment: the machine is ours, so the rows have no paper column except
where a target is stated. Each seed runs the live pipeline on the centre
(:class:`server.pipeline.centre_source.CentreSource`, 500 Hz trace) with the part
:class:`server.pipeline.centre_wear_part.CentreWearPart`; every tool's estimate is
compared with the simulator's flank wear of the instance in the magazine every
``EVERY_S`` seconds of machine time, once that tool's blocks are taught. When the part
detects a new instance (the simulator replaced a worn tool at VB 0.3 mm), the harness
enters the VB "measured" at that change - the simulator's VB of the worn instance plus
a microscope's error (``LABEL_SD``, 10 um) - as an operator would through
``POST /api/tool-lives/vb``; from then on that tool's map is "calibrated".

The tools' lives are scaled by ``LIFE_SCALE`` (0.5: the default lives are minutes of
cutting; half of them give each tool 2-4 lives in an hour of machine time). Rows: MAE
[mm] and the 95 % interval's coverage and median width, uncalibrated (before the
tool's first label) and calibrated, pooled over the seeds and per seed (median, range);
the tool changes the simulator made and those the part detected.
"""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path
from typing import TypedDict

import numpy as np

from common.arrays import F64
from server.experiments.reproduction import Check, Reproduction, Row

NAME = "centre-wear"
SOURCE = "issue 31 item 2 / issue 35 item 7: wear per tool on the machining centre (no paper)"
LIFE_SCALE = 0.5
LABEL_SD = 0.01e-3
EVERY_S = 5.0
SEEDS_QUICK, SECONDS_QUICK = (1,), 300.0
SEEDS_FULL, SECONDS_FULL = (1, 2, 3, 4), 3000.0
#: the coverage the 95 % interval should reach, pooled (checked on the full run)
TARGET_COVERAGE = 0.90


class SeedRun(TypedDict):
    """One seed's run: the samples (8 columns, see :func:`run_seed`) and the tool
    changes made, detected and labelled."""

    rows: F64
    made: int
    detected: int
    labelled: int


def run_seed(
    seed: int, seconds: float, *, life_scale: float = LIFE_SCALE, block: int = 500
) -> SeedRun:
    """One seed: the samples (tool, instance, calibrated, true VB, estimate, low, high)
    [m] and the tool changes made by the simulator and detected by the part."""
    from machine.centre.sim import MachiningCentre
    from server.pipeline.centre_source import CentreSource
    from server.pipeline.centre_wear_part import CentreWearPart
    from server.pipeline.live_pipeline import LivePipeline

    src = CentreSource(seed)
    prog = src.machine.program
    tools = tuple(dataclasses.replace(t, life=t.life * life_scale) for t in prog.tools)
    src.machine = MachiningCentre(program=dataclasses.replace(prog, tools=tools))
    src.reset()
    pipe = LivePipeline("machining-centre", seed=seed, source=src)
    part = next(p for p in pipe._parts if isinstance(p, CentreWearPart))
    rng = np.random.default_rng(1000 + seed)
    inst = {k: v.instance for k, v in src._state.tools.items()}
    last_vb = {k: v.vb() for k, v in src._state.tools.items()}
    worn: dict[int, list[float]] = {k: [] for k in inst}
    rows: list[tuple[float, ...]] = []
    made = detected = labelled = 0
    next_t = EVERY_S
    for _ in range(int(seconds / (block * pipe.sample_time))):
        pipe.step(block)
        for k, ts in src._state.tools.items():
            if ts.instance != inst[k]:
                made += 1
                worn[k].append(last_vb[k])
                inst[k] = ts.instance
            last_vb[k] = ts.vb()
        for c in part.take_tool_changes():
            detected += 1
            tl = int(str(c["tool"]))
            if worn[tl]:
                vb_m = worn[tl].pop(0) + LABEL_SD * float(rng.standard_normal())
                part.label(tl, vb_m * 1e3)
                labelled += 1
        if src.t >= next_t:
            next_t += EVERY_S
            for k, ts in src._state.tools.items():
                e = part.wear.estimate(part.st.est, k)
                if math.isfinite(float(e["vb"])) and part._taught(k):
                    cal = float(bool(e["calibrated"]))
                    rows.append((k, ts.instance, cal, ts.vb(), float(e["vb"]),
                                 float(e["lo"]), float(e["hi"]), src.t))  # fmt: skip
    return {"rows": np.array(rows, dtype=np.float64).reshape(-1, 8), "made": made,
            "detected": detected, "labelled": labelled}  # fmt: skip


def metrics(r: np.ndarray) -> dict[str, float]:
    """MAE [mm], coverage, median width [mm] of samples (rows of :func:`run_seed`)."""
    if len(r) == 0:
        return {"mae": math.nan, "coverage": math.nan, "width": math.nan, "n": 0}
    err = np.abs(r[:, 4] - r[:, 3])
    cov = (r[:, 3] >= r[:, 5]) & (r[:, 3] <= r[:, 6])
    return {"mae": float(np.mean(err)) * 1e3, "coverage": float(np.mean(cov)),
            "width": float(np.median(r[:, 6] - r[:, 5])) * 1e3, "n": len(r)}  # fmt: skip


def _spread(v: list[float]) -> str:
    f = [x for x in v if math.isfinite(x)]
    return f"median {np.median(f):.3g}, range {min(f):.3g}-{max(f):.3g}" if f else "none"


def run(
    *, quick: bool = False, plot_dir: Path | None = None, progress: bool = True
) -> Reproduction:
    """Every seed, then the pooled and per-seed rows (module docstring)."""
    rep = Reproduction(experiment=NAME, source=SOURCE)
    seeds, seconds = (SEEDS_QUICK, SECONDS_QUICK) if quick else (SEEDS_FULL, SECONDS_FULL)
    runs = []
    for i, s in enumerate(seeds):
        if progress:
            print(f"  seed {s} ({i + 1}/{len(seeds)}), {seconds:.0f} s of machine time", flush=True)
        runs.append(run_seed(s, seconds))
    allr = np.vstack([r["rows"] for r in runs])
    cond = f"{len(seeds)} seeds x {seconds:.0f} s, lives x {LIFE_SCALE}, every {EVERY_S:g} s"
    rows: list[Row] = []
    checks: list[Check] = []
    for name, sel in (("uncalibrated", 0.0), ("calibrated", 1.0)):
        m = metrics(allr[allr[:, 2] == sel])
        per = [metrics(r["rows"][r["rows"][:, 2] == sel]) for r in runs]
        rows += [
            Row(f"{name}.mae", m["mae"], None, "mm",
                f"{cond}; {m['n']} samples; per seed {_spread([p['mae'] for p in per])}"),
            Row(f"{name}.coverage", m["coverage"], 0.95, "", "95 % interval; paper = nominal; "
                f"per seed {_spread([p['coverage'] for p in per])}"),
            Row(f"{name}.width", m["width"], None, "mm", "median width of the 95 % interval"),
        ]  # fmt: skip
        for k in sorted({int(x) for x in allr[:, 0]}):
            mk = metrics(allr[(allr[:, 2] == sel) & (allr[:, 0] == k)])
            if mk["n"]:
                what = f"coverage {mk['coverage']:.2f}, width {mk['width']:.3f} mm"
                rows.append(Row(f"{name}.tool.{k}.mae", mk["mae"], None, "mm", what))
        if not quick and m["n"]:
            checks.append(Check(f"{name}.coverage", m["coverage"] >= TARGET_COVERAGE,
                                m["coverage"], TARGET_COVERAGE))  # fmt: skip
    made = sum(r["made"] for r in runs)
    det = sum(r["detected"] for r in runs)
    rows += [
        Row("tool_changes.made", made, None, "", "worn tools the simulator replaced"),
        Row("tool_changes.detected", det, made, "", "new instances the part detected; "
            f"paper = made; labelled {sum(r['labelled'] for r in runs)}"),
    ]  # fmt: skip
    rep.add((rows, checks))
    if plot_dir is not None:
        rep.figures.append(plot(runs[0]["rows"], seeds[0], Path(plot_dir)))
    return rep


def plot(r: np.ndarray, seed: int, out_dir: Path) -> str:
    """Per tool: the simulator's VB, the estimate and its 95 % band over machine time,
    the calibrated stretches shaded (docs/centre-wear.md)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    out_dir.mkdir(parents=True, exist_ok=True)
    tools = sorted({int(x) for x in r[:, 0]})
    fig, axes = plt.subplots(len(tools), 1, figsize=(10, 2.6 * len(tools)), sharex=True,
                             constrained_layout=True, squeeze=False)  # fmt: skip
    for ax, k in zip(axes[:, 0], tools, strict=True):
        q = r[r[:, 0] == k]
        t = q[:, 7] / 60.0
        for inst in sorted({int(x) for x in q[:, 1]}):
            m = q[:, 1] == inst
            ax.fill_between(t[m], 1e3 * q[m, 5], 1e3 * q[m, 6], color="C1", alpha=0.25, lw=0)
            ax.plot(t[m], 1e3 * q[m, 4], color="C1", lw=1.4)
            ax.plot(t[m], 1e3 * q[m, 3], color="k", lw=1.2)
        cal = q[:, 2] > 0
        if cal.any():
            ax.axvspan(t[cal][0], t[-1], color="C2", alpha=0.08, lw=0)
        ax.axhline(0.3, color="#7b3294", ls="--", lw=1)
        ax.set_ylabel(f"T{k}: VB [mm]")
        ax.set_ylim(0, 0.6)
    axes[-1, 0].set_xlabel("machine time [min]")
    axes[0, 0].set_title(f"seed {seed}: simulator's VB (black), estimate and 95 % band (orange); "
                         "green: calibrated (a VB entered at a change)")  # fmt: skip
    path = out_dir / "centre_wear.png"
    fig.savefig(path, dpi=90, bbox_inches="tight")
    plt.close(fig)
    return str(path)


__all__ = ["NAME", "SOURCE", "metrics", "run", "run_seed"]
