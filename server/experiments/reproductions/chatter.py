"""Chatter, part one: stability lobes against a published benchmark and the simulator.

Three sections (docs/chatter.md):

1. **the benchmark** (Insperger & Stepan's 1-DOF milling example, down-milling at
   a/D = 1 and 0.05): the semi-discretization converged (m from 100, doubled until the
   boundary moves less than 0.5 %), the zero-order approximation beside it, the gap over
   the chart, where the ZOA misses the period-doubling lobes (:mod:`._chatter_lobes`);
2. **the simulator**: the time-domain growth criterion on a grid of speeds and depths
   (0.5x-2x the boundary), the points within 10 % of the boundary apart
   (:mod:`._chatter_grid`);
3. **the drives**: the attenuation table, chatter on seed 003's machine with a flexible
   tool (grows, saturates, stops), the table checked on it (:mod:`._chatter_drives`).

Every check's name carries ``lobe``.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from estimators.chatter.lobes import LobeChart
from server.experiments.reproduction import Reproduction
from server.experiments.reproductions import _chatter_drives as drv
from server.experiments.reproductions import _chatter_grid as grd
from server.experiments.reproductions import _chatter_lobes as lob

NAME = "chatter"
SOURCE = (
    "Insperger & Stepan 1-DOF milling benchmark (IJNME 61, 2004); Altintas & Budak ZOA "
    "(CIRP Annals 44, 1995); seed 003's machine"
)
ROWS = [
    "ad<1|0.05>.<rpm>rpm.<sd_depth_mm|sd_change_from_half_m|zoa_depth_mm|zoa_gap>",
    "sd_averaged_vs_zoa",
    "ad1.zoa_gap.<max_abs|median_abs|hopf_median_abs|at_minimum>",
    "ad1.<sd_min_depth_mm|zoa_min_depth_mm|flip_fraction|zoa_within_5pct_fraction>",
    "ad0.05.flip_fraction",
    "ad0.05.flip_lobe<i>.<rpm_from|rpm_to|zoa_over_sd.max>",
    "ad0.05.zoa_gap.hopf_median_abs",
    "grid.<ad1|ad0.05|all>.<agreement_far|agreement_near>",
    "grid.<ad>.<rpm>rpm.x<ratio>.growth (each disagreement)",
    "grid.chatter_freq.<median_abs_diff_hz|max_abs_diff_hz>",
    "drives.<f>hz.<structure_n_per_um|axis_servo_db|spindle_servo_db|average_2ms_db|"
    "average_1ms_db|axis_ma_per_um|trace500_ma_per_um|trace1k_ma_per_um|alias_500_hz|"
    "alias_1k_hz>",
    "drives.flip_20000rpm.<freq_hz|spindle_harmonic|average_2ms_db|average_1ms_db>",
    "demo.<stable_1mm.nonforced_over_forced|onset_after_step_s|developed_after_step_s|"
    "saturated.nonforced_um|saturated.nonforced_over_forced|chatter_freq_hz|"
    "stops_after_speed_change_s|end.nonforced_over_forced>",
    "chain.<axis_current|trace500|spindle>.<measured|predicted>",
    "chain.spindle.<cut_torque_nm_per_um|current_ma_per_um|power_w_per_um>",
]


def run(
    *, quick: bool = False, plot_dir: Path | None = None, progress: bool = True
) -> Reproduction:
    """The three sections; ``quick`` takes fewer speeds and shorter demo phases (every
    check is computed the same way)."""
    from tqdm import tqdm

    rep = Reproduction(NAME, SOURCE)
    n_chart = 2 * (41 if quick else 201)
    n_grid = 2 * len(grd.speeds(quick)) * len(grd.QUICK_RATIOS if quick else grd.RATIOS)
    with tqdm(total=n_chart + n_grid + 3, desc=NAME, disable=not progress, leave=False) as bar:
        charts = lob.charts(quick, tick=lambda: bar.update(1))
        rep.add(lob.converged_section(quick))
        rep.add(lob.averaged_check())
        rep.add(lob.chart_section(charts))
        bar.update(1)
        points = grd.grid(quick, tick=lambda: bar.update(1))
        rep.add(grd.grid_section(points))
        rep.add(drv.table_section())
        bar.update(1)
        demo = drv.demo(quick)
        rep.add(drv.demo_section(demo))
        rep.add(drv.chain_section(demo))
        bar.update(1)
    if plot_dir is not None:
        rep.figures.append(plot_lobes(Path(plot_dir), charts, points))
        rep.figures.append(plot_demo(Path(plot_dir), demo))
    return rep


def plot_lobes(out: Path, charts: dict[float, LobeChart], points: list[grd.GridPoint]) -> str:
    """Speed against depth: SD and ZOA lobes, the simulator's verdicts on top."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axs = plt.subplots(1, 2, figsize=(12, 4.6))
    for ax, imm in zip(axs, lob.IMMERSIONS, strict=True):
        ch = charts[imm]
        ax.plot(ch.rpm, ch.sd_depth * 1e3, "k", lw=1.4, label="semi-discretization")
        ax.plot(ch.rpm, ch.zoa_depth * 1e3, "C0--", lw=1.0, label="zero-order (ZOA)")
        flip = np.array([k == "flip" for k in ch.sd_kind])
        ax.plot(ch.rpm[flip], ch.sd_depth[flip] * 1e3, "r.", ms=3, label="SD: period doubling")
        sel = [p for p in points if p.immersion == imm]
        for stable, mark, lab in (
            (True, "o", "simulator: stable"),
            (False, "x", "simulator: chatter"),
        ):
            pts = [p for p in sel if p.sim.stable == stable]
            col = ["C2" if p.agrees else "m" for p in pts]
            ax.scatter([p.rpm for p in pts], [p.depth * 1e3 for p in pts], marker=mark, c=col, s=18)
            ax.scatter([], [], marker=mark, c="k", s=18, label=lab)  # the legend's entry
        ax.set_xlabel("spindle speed [rpm]")
        ax.set_ylabel("axial depth [mm]")
        ax.set_title(f"Insperger-Stepan 1-DOF benchmark, down-milling a/D = {imm:g}")
        top = 3.0 * float(np.nanmedian(ch.sd_depth[np.isfinite(ch.sd_depth)])) * 1e3
        ax.set_ylim(0, top)
        ax.legend(fontsize=7, loc="upper left")
    fig.text(
        0.01, 0.01, "simulator points: green = agrees with SD, magenta = disagrees", fontsize=8
    )
    fig.tight_layout(rect=(0, 0.03, 1, 1))
    out.mkdir(parents=True, exist_ok=True)
    path = out / "chatter_lobes.png"
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return str(path)


def plot_demo(out: Path, run: drv.DemoRun) -> str:
    """The demo's vibration, non-forced amplitude and axis current over time."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    r = run.rec
    fig, axs = plt.subplots(3, 1, figsize=(10, 7), sharex=True)
    axs[0].plot(run.t, r["qx"] * 1e6, lw=0.4, label="tool vibration X")
    axs[0].set_ylabel("[um]")
    axs[1].plot(run.t, r["amp_nonforced"] * 1e6, label="non-forced amplitude")
    axs[1].plot(run.t, r["amp_forced"] * 1e6, label="forced amplitude")
    axs[1].set_ylabel("[um]")
    axs[2].plot(run.t, r["ix"], lw=0.4, label="X motor current")
    axs[2].set_ylabel("[A]")
    axs[2].set_xlabel("time [s]")
    for ax in axs:
        for tt in (run.t_deep, run.t_speed):
            ax.axvline(tt, color="k", lw=0.6, ls=":")
        ax.legend(fontsize=8, loc="upper left")
    axs[0].set_title("seed 003's machine, flexible tool: depth 1 -> 4 mm, then 1200 -> 3000 rpm")
    fig.tight_layout()
    out.mkdir(parents=True, exist_ok=True)
    path = out / "chatter_demo.png"
    fig.savefig(path, dpi=100)
    plt.close(fig)
    return str(path)
