"""A measured log through the rigid residual model, with the choices its sampling rate
allows (:func:`estimators.residual.rate.rate_plan`): the command ``cutwatch residual``
and the ``cnc-mill`` reproduction build the model the same way."""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any, TypedDict

from common.state_io import JsonNode
from server.records.measured_log import MeasuredLog


def rigid_model(log: MeasuredLog) -> Any:
    """The rigid model of ``log`` (:class:`estimators.residual.rigid.RigidModel`).

    The controller's velocity and acceleration are used when the log maps ``qd_m``
    (``qdd_m``); the record is cut where rows were left out; the ``load`` family is
    offered on the rows ``--load-rows`` marks, the nominal model fitted on the rows
    ``--nominal-rows`` marks; below 100 Hz only the families a static map can identify
    are offered, the others named with the reason.
    """
    from estimators.residual.families import FAMILIES as REGISTRY
    from estimators.residual.rate import rate_plan
    from estimators.residual.rigid import RigidModel

    qd = log.columns.get("qd_m")
    plan = rate_plan(log.sample_time, velocity_given=qd is not None)
    load = log.phases.get("load_rows")
    families = None
    if plan.families is not None:
        families = {k: REGISTRY[k] for k in plan.families if k != "load" or load is not None}
    cut = len(log.segments) > 1
    model = RigidModel(
        log["q_m"], log["tau_m"], log["t"], log.sample_time, idim=plan.idim,
        families=families, qd=qd, qdd=log.columns.get("qdd_m"),
        segments=log.segments if cut else None, load=load,
        nominal_rows=log.phases.get("nominal_rows"),
    )  # fmt: skip
    model.not_offered = {**model.not_offered, **plan.not_identifiable}
    return model


def model_notes(log: MeasuredLog, kind: str = "rigid") -> list[str]:
    """What the report says about the rate, the rows used and the effort's unit."""
    from estimators.residual.rate import rate_plan

    notes: list[str] = []
    if kind == "rigid":
        plan = rate_plan(log.sample_time, velocity_given="qd_m" in log.columns)
        if plan.note:
            notes.append(plan.note)
    if len(log.segments) > 1:
        notes.append(
            f"the row selection cuts the record into {len(log.segments)} pieces: nothing "
            "is differentiated or filtered across a cut"
        )
    if log.units.get("effort") == "A":
        notes.append("effort in A (no torque constant given): parameters in A, A s/m, A s^2/m")
    if "nominal_rows" in log.phases:
        notes.append(
            f"nominal model ('before') fitted on the {int(log.phases['nominal_rows'].sum())} "
            "rows --nominal-rows marks (inside the fitting part); the effects and the final "
            "model refit on every fitting row"
        )
    return notes


class EffectFit(TypedDict):
    """A selected effect and its fitted parameters."""

    name: str
    params: dict[str, float]


class CncAxisReport(TypedDict):
    """:func:`analyse_cnc_axis`'s numbers: the held-out errors before and after, the
    effects, each candidate's (cross-validated effect, p-value, note), the nominal fit."""

    relerr_before: float
    relerr_after: float
    rms_before: float
    rms_after: float
    selected: list[str]
    effects: list[EffectFit]
    candidates: dict[str, tuple[float, float, str]]
    unexplained: list[dict[str, float | str]]
    r2_nominal: float
    nominal: dict[str, float]
    notes: list[str]
    rows_read: int
    rows_used: int


def analyse_cnc_axis(
    path: Path,
    meta: Mapping[str, JsonNode],
    maps: Sequence[str],
    *,
    drop: Sequence[str] = (),
    drop_repeats: str | None = None,
    load: str | None = None,
    holdout: float = 0.3,
    progress: Callable[[str], None] | None = None,
) -> CncAxisReport:
    """One axis of a CNC export through the loop; the report's numbers as a dict."""
    import numpy as np

    from estimators.residual.engine import ResidualParams, analyse
    from server.records.measured_log import load_log
    from server.records.row_select import RowSelection

    sel = RowSelection.from_options(
        drop=drop, drop_repeats=drop_repeats, phases={"load_rows": load}
    )
    log = load_log(path, meta=meta, maps=maps, selection=sel, current_ok=True)
    model = rigid_model(log)
    notes = model_notes(log)
    res = analyse(model, ResidualParams(holdout_fraction=holdout), progress=progress)
    y = log["tau_m"]
    e0 = y - res.f_hat_before
    r2 = 1.0 - float(np.sum(e0**2) / np.sum((y - y.mean()) ** 2))
    byname = {c.name: c for c in res.candidates}
    return {
        "relerr_before": res.relerr_before,
        "relerr_after": res.relerr_after,
        "rms_before": res.rms_before,
        "rms_after": res.rms_after,
        "selected": [e.name for e in res.effects],
        "effects": [{"name": e.name, "params": dict(byname[e.name].params)} for e in res.effects],
        "candidates": {c.name: (c.cv_effect, c.p_value, c.note) for c in res.candidates},
        "unexplained": list(res.unexplained),
        "r2_nominal": r2,
        "nominal": dict(zip(res.names_before, map(float, res.theta_before))),
        "notes": notes,
        "rows_read": log.n_read,
        "rows_used": log.n,
    }
