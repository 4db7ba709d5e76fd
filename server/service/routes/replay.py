"""``POST /api/replay`` (a measured log through the live observers), the identified
observer effects (``GET``/``POST``/``DELETE /api/observer-effects``) and the residual
report's effects in the axes' live rigid models (``GET``/``POST``/``DELETE
/api/axis-model``)."""

from __future__ import annotations

import json
from collections.abc import Iterable
from pathlib import Path
from typing import TYPE_CHECKING, Any, TypedDict

from fastapi import APIRouter

from common.jsonsafe import json_safe
from server.errors import CutwatchError
from server.service.datafiles import find_log, find_report, refuse_path, scrub
from server.service.deps import Authorised, Config, LiveEffects, Store
from server.service.http_errors import FieldError
from server.service.schemas import (
    AxisModelBody,
    AxisModels,
    Effects,
    EffectsBody,
    EffectsInstalled,
    Replay,
    ReplayStarted,
    error_responses,
)

if TYPE_CHECKING:
    from estimators.observer_effects import ObserverEffect

router = APIRouter(prefix="/api", tags=["replay"], responses=error_responses())

_LOG_RULE = "a two_inertia log (.csv with its .json sidecar, or .mat) in the data areas"


@router.post(
    "/replay",
    summary="replay a two_inertia log (a recording or an upload, by name) through the live "
    "observers",
    dependencies=[Authorised],
    response_model=ReplayStarted,
    responses=error_responses(413, 422),
)
def replay(body: Replay, lp: LiveEffects, s: Config, st: Store) -> ReplayStarted:
    from server.pipeline.live_pipeline import LivePipeline
    from server.pipeline.sources import ReplaySource, open_replay

    if body.path is not None:
        raise refuse_path(body.path)
    if body.name is None:
        raise FieldError("name", _LOG_RULE, None, f"name: expected {_LOG_RULE}")
    area, p = find_log(st, body.name, body.area)
    try:
        log = open_replay(p)
        pipe = LivePipeline(seed=s.seed, source=ReplaySource(log))
    except CutwatchError as exc:
        raise FieldError("name", _LOG_RULE, body.name, scrub(str(exc), p, p.name)) from None
    lp.set_pipeline(pipe)
    n = len(log["t"])
    return ReplayStarted(
        scenario="replay",
        name=p.name,
        area=area,
        samples=n,
        sample_time=log.sample_time,
        duration_s=n * log.sample_time,
        reference_force="f_ext" in log.columns,
    )


@router.get(
    "/observer-effects",
    summary="effects installed in the live observer",
    response_model=Effects,
)
def get_effects(lp: LiveEffects) -> Effects:
    return Effects.model_validate({"observer_effects": _effects_json(lp.observer_effects())})


@router.post(
    "/observer-effects",
    summary="install identified effects (a residual report by name, or its observer_effects)",
    dependencies=[Authorised],
    response_model=EffectsInstalled,
    responses=error_responses(413, 422),
)
def post_effects(body: EffectsBody, lp: LiveEffects, st: Store) -> EffectsInstalled:
    if body.path is not None:
        raise refuse_path(body.path, "report")
    if (body.report is None) == (body.observer_effects is None):
        raise FieldError(
            "body",
            "exactly one of 'report' or 'observer_effects'",
            "both" if body.report is not None else "neither",
            "expected one of 'report' (a residual report's name) or 'observer_effects'",
        )
    path = find_report(st, body.report) if body.report is not None else None
    effects, skipped = parse_effects(path, body.observer_effects)
    installed, t = lp.set_observer_effects(effects)
    return EffectsInstalled.model_validate(
        {"observer_effects": _effects_json(installed), "skipped": skipped, "t": t}
    )


@router.delete(
    "/observer-effects",
    summary="remove the installed effects",
    dependencies=[Authorised],
    response_model=Effects,
    responses=error_responses(),
)
def delete_effects(lp: LiveEffects) -> Effects:
    lp.set_observer_effects(())
    return Effects(observer_effects=[])


@router.get("/axis-model", summary="the report's effects in the axes' live models",
            response_model=AxisModels)  # fmt: skip
def get_axis_model(lp: LiveEffects) -> AxisModels:
    axes, t = lp.axis_effects()
    return AxisModels(axes=axes, t=t)


@router.post(
    "/axis-model",
    summary="load a rigid residual report's effects into an axis' live model (by name, or "
    "the report): their coefficients identified live with M, Fv, Fc",
    dependencies=[Authorised],
    response_model=AxisModels,
    responses=error_responses(413, 422),
)
def post_axis_model(body: AxisModelBody, lp: LiveEffects, st: Store) -> AxisModels:
    from server.errors import LogFormatError
    from server.pipeline.axis_part import ALL_AXES
    from server.records.residual_report import live_effects

    if (body.name is None) == (body.report is None):
        raise FieldError(
            "body",
            "exactly one of 'name' or 'report'",
            "both" if body.name is not None else "neither",
            "expected one of 'name' (a residual report's name) or 'report' (its JSON)",
        )
    rep: Any = body.report
    if body.name is not None:
        rep = json.loads(find_report(st, body.name).read_text())
    try:
        effects = tuple(live_effects(rep, "report"))
    except LogFormatError as exc:
        raise FieldError("report", "a rigid residual report", body.name, str(exc)) from None
    lp.set_axis_effects({body.axis or ALL_AXES: effects})
    axes, t = lp.axis_effects()
    return AxisModels(axes=axes, t=t)


@router.delete(
    "/axis-model",
    summary="the axes' live models without any report's effects",
    dependencies=[Authorised],
    response_model=AxisModels,
    responses=error_responses(),
)
def delete_axis_model(lp: LiveEffects) -> AxisModels:
    lp.set_axis_effects({})
    axes, t = lp.axis_effects()
    return AxisModels(axes=axes, t=t)


class EffectJson(TypedDict):
    """An installed effect as the answers list it (non-finite numbers null)."""

    name: str  # its family
    side: str  # the observer's side it acts on
    shape: dict[str, float | None]  # its shape's parameters
    coef: list[float | None]  # its fitted coefficients


def _effects_json(effects: Iterable[ObserverEffect]) -> list[EffectJson]:
    out: list[EffectJson] = json_safe(
        [{"name": e.name, "side": e.side, "shape": dict(e.shape), "coef": list(e.coef)}
         for e in effects]
    )  # fmt: skip
    return out


#: effect families referenced to the log's time axis (a drift from its t0, a harmonic of
#: its clock's phase); not installed live: the live clock is another one
LOG_TIME_EFFECTS = ("drift", "harmonic")

_EFFECT_RULE = "{'name': str, 'shape': {str: number}, 'coef': [number, ...]}"


def parse_effects(
    path: str | Path | None, items: list[dict[str, Any]] | None
) -> tuple[tuple[Any, ...], list[str]]:
    """Effects from a report.json (resolved by the caller inside the reports area) or an
    ``observer_effects`` list, and the names of those skipped (:data:`LOG_TIME_EFFECTS`).

    Raises
    ------
    FieldError
        Neither or both given, unreadable report, or malformed entries.
    ParameterError
        An entry that :class:`estimators.observer_effects.ObserverEffect` refuses.
    """
    from estimators.observer_effects import ObserverEffect

    if (path is None) == (items is None):
        raise FieldError(
            "body",
            "exactly one of 'report' or 'observer_effects'",
            "both" if path is not None else "neither",
            "expected one of 'report' (a residual report's name) or 'observer_effects'",
        )
    if path is not None:
        p = Path(path)
        name = p.parent.name
        rule = "a residual report of 'cutwatch residual --kind two_inertia'"
        try:
            rep = json.loads(p.read_text())
        except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
            raise FieldError(
                "report", rule, name, f"report {name!r}: not a readable JSON report: "
                + scrub(str(exc), p, "report.json")
            ) from None  # fmt: skip
        items = rep.get("observer_effects") if isinstance(rep, dict) else None
        if not isinstance(items, list):
            raise FieldError(
                "report",
                rule,
                name,
                f"report {name!r}: no 'observer_effects' list (expected a report of "
                "'cutwatch residual --kind two_inertia')",
            )
    out = []
    skipped = []
    for i, e in enumerate(items or []):
        shape: Any = e.get("shape", {}) if isinstance(e, dict) else None
        coef: Any = e.get("coef") if isinstance(e, dict) else None
        ok = isinstance(e, dict) and isinstance(e.get("name"), str)
        ok = ok and isinstance(shape, dict) and isinstance(coef, list)
        ok = ok and all(_is_number(v) for v in coef) and all(_is_number(v) for v in shape.values())
        if not ok:
            raise FieldError(
                f"observer_effects[{i}]",
                _EFFECT_RULE,
                e,
                f"observer_effects[{i}]: expected {_EFFECT_RULE}, got {e!r}"[:300],
            )
        if e["name"] in LOG_TIME_EFFECTS:
            # referenced to the log's own clock: meaningless on the live clock
            skipped.append(e["name"])
            continue
        out.append(ObserverEffect(e["name"], dict(shape), tuple(float(c) for c in coef)))
    return tuple(out), skipped


def _is_number(v: Any) -> bool:
    return isinstance(v, int | float) and not isinstance(v, bool)
