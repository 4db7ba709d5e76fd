"""``GET``/``PATCH /api/params``: the live knobs, checked field by field, all or nothing."""

from __future__ import annotations

import contextlib
from typing import Any

from fastapi import APIRouter, HTTPException

from common.errors import ParameterError
from server.pipeline.live_pipeline import Knob
from server.service.deps import Authorised, Live
from server.service.http_errors import echo, error
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
    # types are the request model's to check (KnobValue), ranges and choices the
    # pipeline's (set_knob, one message per knob); all fields are tried, then undone
    # when any is refused
    changes = body.root
    with lp.lock:
        knobs = lp.pipeline.knobs()
        if not changes:
            allowed = "an object with at least one of " + ", ".join(knobs)
            raise HTTPException(422, detail=[error("body", allowed, {}, "no field given")])
        old = {name: knobs[name].value for name in changes if name in knobs}
        errors: list[dict[str, Any]] = []
        for name, value in changes.items():
            if name not in knobs:
                allowed = "one of " + ", ".join(knobs)
                msg = f"unknown parameter {echo(name)!r}; expected {allowed}"
                errors.append(error(name, allowed, value, msg))
                continue
            try:
                lp.pipeline.set_knob(name, value)
            except ParameterError as exc:
                allowed = exc.expected
                msg = f"{name}: expected {allowed}, got {echo(value)!r}"
                errors.append(error(name, allowed, value, msg))
        if errors:
            for name, v in old.items():
                with contextlib.suppress(ParameterError):
                    lp.pipeline.set_knob(name, v)
            raise HTTPException(422, detail=errors)
        return _params(lp)
