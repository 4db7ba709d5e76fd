"""``GET``/``PATCH /api/params``: the live knobs, checked field by field, all or nothing."""

from __future__ import annotations

import contextlib
import math
from typing import Any

from fastapi import APIRouter, HTTPException

from common.errors import ParameterError
from server.pipeline.live_pipeline import Knob
from server.service.deps import Authorised, Live
from server.service.http_errors import _json_safe, error
from server.service.schemas import Params, ParamsPatch, error_responses

router = APIRouter(responses=error_responses())


def _knob_dict(k: Knob) -> dict[str, Any]:
    d: dict[str, Any] = {"value": k.value, "unit": k.unit, "doc": k.doc}
    if isinstance(k.value, bool):
        d["type"] = "bool"
    elif k.choices is not None:
        d["type"] = "choice"
        d["choices"] = list(k.choices)
    else:
        d["type"] = "number"
        d["min"], d["max"] = k.min, k.max
    return d


def _params(lp: Any) -> Params:
    return Params.model_validate({name: _knob_dict(k) for name, k in lp.pipeline.knobs().items()})


def _check_knob(name: str, k: Knob, value: Any) -> tuple[Any, dict[str, Any] | None]:
    """Validate one PATCH field against its knob; return (value, None) or (None, error)."""
    if isinstance(k.value, bool):
        if not isinstance(value, bool):
            return None, error(
                name,
                "true or false",
                value,
                f"{name}: expected true or false, got {_json_safe(value)!r}",
            )
        return value, None
    if k.choices is not None:
        if not isinstance(value, str) or value not in k.choices:
            allowed = "one of " + ", ".join(k.choices)
            return None, error(
                name, allowed, value, f"{name}: expected {allowed}, got {_json_safe(value)!r}"
            )
        return value, None
    allowed = f"a number in [{k.min:g}, {k.max:g}] {k.unit}".rstrip()
    ok = isinstance(value, int | float) and not isinstance(value, bool)
    ok = ok and math.isfinite(float(value))
    ok = ok and (k.min is None or float(value) >= k.min)
    ok = ok and (k.max is None or float(value) <= k.max)
    if not ok:
        return None, error(
            name, allowed, value, f"{name}: expected {allowed}, got {_json_safe(value)!r}"
        )
    return float(value), None


@router.get(
    "/api/params", summary="live parameters with their allowed ranges", response_model=Params
)
def params(lp: Live) -> Params:
    with lp.lock:
        return _params(lp)


@router.patch(
    "/api/params",
    summary="change live parameters (all or nothing)",
    dependencies=[Authorised],
    response_model=Params,
    responses=error_responses(413, 422),
)
def patch_params(body: ParamsPatch, lp: Live) -> Params:
    changes = body.root
    with lp.lock:
        knobs = lp.pipeline.knobs()
        errors: list[dict[str, Any]] = []
        clean: dict[str, Any] = {}
        if not changes:
            errors.append(
                error(
                    "body",
                    "an object with at least one of " + ", ".join(knobs),
                    changes,
                    "no field given",
                )
            )
        for name, value in changes.items():
            if name not in knobs:
                allowed = "one of " + ", ".join(knobs)
                errors.append(
                    error(name, allowed, value, f"unknown parameter {name!r}; expected {allowed}")
                )
                continue
            v, err = _check_knob(name, knobs[name], value)
            if err is not None:
                errors.append(err)
            else:
                clean[name] = v
        if errors:
            raise HTTPException(422, detail=errors)
        old = {name: knobs[name].value for name in clean}
        try:
            for name, v in clean.items():
                lp.pipeline.set_knob(name, v)
        except ParameterError:
            for name, v in old.items():
                with contextlib.suppress(ParameterError):
                    lp.pipeline.set_knob(name, v)
            raise
        return _params(lp)
