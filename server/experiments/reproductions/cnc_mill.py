"""A real CNC's 10 Hz exports through the residual loop (issue 18 item 2).

Data: ``../shared/data/cnc-mill/experiment_NN.csv`` (University of Michigan SMART lab,
"CNC Mill Tool Wear", 2018, public domain CC0): wax blocks milled with an "S" shape, one
row per 100 ms, per axis position [mm], velocity [mm/s], acceleration [mm/s^2] and
current [A], a text label of the machining phase. Every ``experiment_*.csv`` found there
is run, X and Y axes, each as ``cutwatch residual`` runs it:

* the rows used: the rows that do not reflect the machine are left out: the machine idle
  at its home position (spindle stopped, every axis at the end of its travel in that
  file; on the given files X, Y, Z at 198, 158, 119 mm), interleaved in 1-s blocks
  between machining blocks in five of the six files (:func:`idle_rule`), and rows
  that repeat the previous row in every drive column (:data:`REPEATS`);
* the controller's velocity and acceleration columns, not a difference of the position
  (exported to 3 significant digits: 1 mm at 198 mm);
* the cutting load on the rows where the tool is in the part (spindle running, Z below
  the middle of the heights the running tool visits, :func:`cutting_rule`), not the phase
  label: in five of the six
  files the labels are in time order but the drive rows are not (1-s blocks out of
  order: positions jump where the velocities cannot take them), so the labels disagree
  with the drive state (measured per file: ``label_disagrees``);
* the nominal model: current = M*qdd + Fv*qd + Fc*sign(qd) + offset, in A (no torque
  constant is given) — the least-squares fit a user would try first (the data README's:
  R^2 = 0.64 on X, 0.57 on Y of experiment 1), the baseline beside each row.

Rows per experiment and axis: held-out relative error of the nominal model (the
baseline) and after the selected effects, the effects, the rows left out. Checks: the
nominal fit reproduces the README's R^2 on experiment 1, the selection never makes the
held-out error worse, and how many runs gain.
"""

from __future__ import annotations

import os
import re
from pathlib import Path

import numpy as np

from common.state_io import JsonNode
from server.errors import CutwatchError
from server.experiments.reproduction import Check, Reproduction, Row
from server.pipeline.residual_run import CncAxisReport

NAME = "cnc-mill"
SOURCE = (
    "U. Michigan SMART lab CNC Mill Tool Wear (2018, CC0), 10 Hz exports; baseline: the "
    "least-squares current model a user would try first (data README: R^2 0.64 / 0.57 on "
    "experiment 1's X / Y)"
)
AXES: tuple[str, ...] = ("X", "Y")
#: the export has no time column: one row per 100 ms; current in A, positions in mm
META: dict[str, JsonNode] = {"sample_time": 0.1, "units": {"effort": "A", "position": "m"}}
#: a stale copy of the previous row in every drive column
REPEATS = "X1_*,Y1_*,Z1_*,S1_*"


class CncRun(CncAxisReport):
    """One experiment's axis: the loop's report, the experiment and axis, the order
    facts of the file and the README baseline's R^2 on all its rows."""

    exp: str
    axis: str
    facts: dict[str, float]
    r2_all_raw: float


def idle_rule(path: Path) -> str:
    """The machine idle at home, found in the file's own drive data: spindle stopped and
    every axis at the end of its travel in this export (a CNC's reference point; no
    position is taken from the given files: a machine homed elsewhere gets its own)."""
    top = _column_extremes(path, ("X1_ActualPosition", "Y1_ActualPosition", "Z1_ActualPosition"))
    at_home = " & ".join(f"{c}=={hi:.6g}" for c, (_, hi) in top.items())
    return f"S1_ActualVelocity<1 & {at_home}"


def cutting_rule(path: Path) -> str:
    """The tool in the part, from the file's own drive data: spindle running and Z below
    the middle of the heights the running tool visits (the layers at the bottom, the
    clearance plane at the top; no block height is taken from the given files)."""
    ((lo, hi),) = _column_extremes(path, ("Z1_ActualPosition",), "S1_ActualVelocity", 1.0).values()
    return f"S1_ActualVelocity>1 & Z1_ActualPosition<{0.5 * (lo + hi):.6g}"


def _column_extremes(
    path: Path, cols: tuple[str, ...], where: str | None = None, above: float = 0.0
) -> dict[str, tuple[float, float]]:
    """(min, max) of numeric columns, over the rows where ``where`` > ``above`` if given."""
    import csv

    with path.open(newline="", encoding="utf-8") as fh:
        rows = [r for r in csv.DictReader(fh) if where is None or float(r[where]) > above]
    if not rows:
        raise CutwatchError(f"{path.name}: no rows with {where} > {above} to find the rule on")
    return {c: (min(float(r[c]) for r in rows), max(float(r[c]) for r in rows)) for c in cols}


#: the data README's R^2 of the plain fit on experiment 1, all 1,055 rows
README_R2 = {"X": 0.64, "Y": 0.57}
QUICK_EXPERIMENTS = ("experiment_01.csv",)


def data_dir() -> Path:
    """The exports: ``$CUTWATCH_CNC_MILL`` or ``shared/data/cnc-mill`` in a parent of the
    working directory or of this file."""
    env = os.environ.get("CUTWATCH_CNC_MILL")
    if env:
        return Path(env)
    rel = Path("shared") / "data" / "cnc-mill"
    for base in (Path.cwd(), *Path.cwd().parents, *Path(__file__).resolve().parents):
        if (base / rel / "experiment_01.csv").is_file():
            return base / rel
    raise CutwatchError(
        f"cnc-mill data: expected ../shared/data/cnc-mill/experiment_NN.csv (or "
        f"CUTWATCH_CNC_MILL=DIR), found no {rel} above {Path.cwd()}"
    )


def axis_maps(axis: str) -> list[str]:
    """The ``--map`` entries of one axis (mm to m; current stays in A)."""
    a = f"{axis}1_"
    return [
        f"q_m={a}ActualPosition*0.001",
        f"tau_m={a}CurrentFeedback",
        f"qd_m={a}ActualVelocity*0.001",
        f"qdd_m={a}ActualAcceleration*0.001",
    ]


def command(path: Path, axis: str, out: str) -> list[str]:
    """The ``cutwatch residual`` arguments of one run (as the docs show it)."""
    import json

    args = [str(path), "--meta", json.dumps(META)]
    for m in axis_maps(axis):
        args += ["--map", m]
    idle, cutting = idle_rule(path), cutting_rule(path)
    return [*args, "--drop", idle, "--drop-repeats", REPEATS, "--load-rows", cutting, "--out", out]


def order_facts(path: Path) -> dict[str, float]:
    """Measured on the raw export: position jumps the velocities cannot explain (rows out
    of time order) and rows whose phase label disagrees with the drive state."""
    from server.records.measured_log import load_log
    from server.records.row_select import RowSelection

    sel = RowSelection.from_options(
        drop=[idle_rule(path)],
        phases={"cutting": cutting_rule(path), "layer": "Machining_Process~^Layer"},
    )
    log = load_log(path, meta=META, maps=axis_maps("X"), selection=sel, current_ok=True)
    q, v = log["q_m"] * 1000.0, log["qd_m"] * 1000.0
    rows = log.row_numbers
    consecutive = np.diff(rows) == 1
    # 3 significant digits: 1 mm at 100 mm and up, 0.1 mm below
    quantum = np.where(np.abs(q) >= 100.0, 1.0, 0.1)
    step = np.abs(np.diff(q) - 0.05 * (v[1:] + v[:-1]))
    jump = consecutive & (step > quantum[1:] + quantum[:-1] + 0.05 * np.abs(np.diff(v)))
    disagree = log.phases["cutting"] != log.phases["layer"]
    return {
        "jumps": float(jump.sum()),
        "label_disagrees": float(disagree.mean()),
        "rows_used": float(log.n),
        "rows_read": float(log.n_read),
    }


def baseline_r2(path: Path, axis: str) -> float:
    """R^2 of the fit a user would try first, on every row of the export: the current on
    acceleration, velocity, sign of velocity and an offset (the data README's 0.64 /
    0.57 on experiment 1)."""
    from server.records.measured_log import load_log

    log = load_log(path, meta=META, maps=axis_maps(axis), current_ok=True)
    v, a, y = log["qd_m"], log["qdd_m"], log["tau_m"]
    x = np.column_stack([a, v, np.sign(v), np.ones_like(v)])
    coef, *_ = np.linalg.lstsq(x, y, rcond=None)
    e = y - x @ coef
    return float(1.0 - np.sum(e**2) / np.sum((y - y.mean()) ** 2))


def _exp_name(path: Path) -> str:
    m = re.search(r"(\d+)", path.stem)
    return f"exp{m.group(1)}" if m else path.stem


def run(
    *, quick: bool = False, plot_dir: Path | None = None, progress: bool = True
) -> Reproduction:
    """Every export found, X and Y (``quick``: experiment 1 only, the same checks)."""
    from tqdm import tqdm

    from server.pipeline.residual_run import analyse_cnc_axis

    d = data_dir()
    files = sorted(d.glob("experiment_*.csv"))
    if quick:
        files = [f for f in files if f.name in QUICK_EXPERIMENTS]
    if not files:
        raise CutwatchError(f"{d}: expected experiment_NN.csv files, found none")
    rep = Reproduction(NAME, SOURCE)
    runs: list[CncRun] = []
    bar = tqdm(total=len(files) * len(AXES), desc=NAME, disable=not progress, leave=False)
    for path in files:
        facts = order_facts(path)
        for axis in AXES:
            rep_axis = analyse_cnc_axis(
                path,
                META,
                axis_maps(axis),
                drop=[idle_rule(path)],
                drop_repeats=REPEATS,
                load=cutting_rule(path),
            )
            r: CncRun = {
                **rep_axis,
                "exp": _exp_name(path),
                "axis": axis,
                "facts": facts,
                "r2_all_raw": baseline_r2(path, axis),
            }
            runs.append(r)
            bar.update(1)
    bar.close()
    for r in runs:
        _rows(rep, r)
    _checks(rep, runs)
    if plot_dir is not None:
        rep.figures.append(str(_plot(runs, plot_dir)))
    return rep


def _unit(param: str) -> str:
    """The unit of an effect parameter on these logs (effort in A, position in m)."""
    if param.startswith("v_s"):
        return "m/s"
    if param.startswith(("Fv", "abs_v", "k_v", "dFv")):
        return "A s/m"
    return "A"


def _rows(rep: Reproduction, r: CncRun) -> None:
    key = f"{r['exp']}.{r['axis']}"
    f = r["facts"]
    used = f"rows {r['rows_used']} of {r['rows_read']} used"
    effects = ", ".join(r["selected"]) or "none"
    rep.rows += [
        Row(f"{key}.heldout_relerr (paper: nominal LS)", r["relerr_after"], r["relerr_before"],
            "%", f"{used}; effects: {effects}"),
        Row(f"{key}.heldout_rms (paper: nominal LS)", r["rms_after"], r["rms_before"], "A",
            "what is left unexplained"),
        Row(f"{key}.nominal_r2_rows_used", r["r2_nominal"], None, "", "nominal LS, rows used"),
    ]  # fmt: skip
    for e in r["effects"]:
        for k, v in e["params"].items():
            if isinstance(v, int | float):
                rep.rows.append(Row(f"{key}.{e['name']}.{k}", float(v), None, _unit(k), ""))
    load = r["candidates"].get("load")
    if load is not None:
        cv, p, note = load
        rep.rows.append(
            Row(f"{key}.load.cv_effect", cv, None, "", f"offered, p = {p:.3g} {note}".strip())
        )
    if r["axis"] == AXES[0]:
        rep.rows += [
            Row(f"{r['exp']}.rows_left_out", r["rows_read"] - r["rows_used"], None, "rows",
                "machine idle at home, stale repeats"),
            Row(f"{r['exp']}.position_jumps", f["jumps"], None, "rows",
                "consecutive rows the velocities cannot join (out of time order)"),
            Row(f"{r['exp']}.label_disagrees", f["label_disagrees"], None, "fraction",
                "label 'Layer' vs tool in the part (drive data)"),
        ]  # fmt: skip


def _checks(rep: Reproduction, runs: list[CncRun]) -> None:
    for r in runs:
        if r["exp"] == "exp01":
            ax = r["axis"]
            rep.checks.append(
                Check(
                    f"exp01.{ax}: the nominal fit on all rows reproduces the README's R^2 "
                    f"{README_R2[ax]} (within 0.03)",
                    abs(r["r2_all_raw"] - README_R2[ax]) <= 0.03,
                    r["r2_all_raw"],
                    README_R2[ax],
                )
            )
    worse = [r["relerr_after"] - r["relerr_before"] for r in runs]
    rep.checks.append(
        Check(
            "no run's held-out error gets worse (largest increase, % points)",
            max(worse) <= 1e-9,
            max(worse),
            0.0,
        )
    )
    gains = [1.0 - r["relerr_after"] / r["relerr_before"] for r in runs]
    rep.checks.append(
        Check(
            "median held-out gain over the runs (target >= 0.10)",
            float(np.median(gains)) >= 0.10,
            float(np.median(gains)),
            0.10,
        )
    )


def _plot(runs: list[CncRun], plot_dir: Path) -> Path:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    plot_dir.mkdir(parents=True, exist_ok=True)
    names = [f"{r['exp']} {r['axis']}" for r in runs]
    x = np.arange(len(runs))
    fig, ax = plt.subplots(figsize=(10, 3.5))
    ax.bar(x - 0.2, [r["relerr_before"] for r in runs], 0.4, color="0.6", label="nominal LS")
    ax.bar(x + 0.2, [r["relerr_after"] for r in runs], 0.4, color="tab:green",
           label="with effects")  # fmt: skip
    ax.set_xticks(x, names, rotation=45, ha="right")
    ax.set_ylabel("held-out relative error [%]")
    ax.legend()
    fig.tight_layout()
    out = plot_dir / "cnc_mill.png"
    fig.savefig(out, dpi=90)
    plt.close(fig)
    return out
