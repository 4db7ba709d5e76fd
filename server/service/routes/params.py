"""``GET``/``PATCH /api/params``: the live knobs, checked field by field, all or nothing.

The knobs are the running pipeline's: those its parts read (``LivePipeline.knobs``). A
knob of the table that none of them reads is refused with a 422 naming it, what is
expected (the knobs offered) and the parts that would read it: a scenario switch starts
from that scenario's defaults, so a value stored for a part this pipeline never builds
would be lost without a word. A part that is built but paused keeps its knobs (their
``waiting`` says why): the value applies when it runs again.
"""

from __future__ import annotations

from typing import Any

from fastapi import APIRouter, HTTPException

from common.errors import ParameterError
from server.pipeline.knobs import KNOBS, Knob, KnobValue, not_read
from server.service.deps import Authorised, Knobs
from server.service.http_errors import ErrorEntry, echo, error
from server.service.schemas import (
    BoolKnob,
    ChoiceKnob,
    NumberKnob,
    Params,
    ParamsPatch,
    error_responses,
)

router = APIRouter(prefix="/api/params", tags=["params"], responses=error_responses())


def _knob_out(k: Knob) -> NumberKnob | BoolKnob | ChoiceKnob:
    """A knob as ``/api/params`` lists it: its kind, value, unit, doc and what it allows."""
    v = k.value
    parts, waiting, page = list(k.parts), k.waiting, k.page
    if isinstance(v, bool):
        return BoolKnob(
            type="bool", value=v, unit=k.unit, doc=k.doc, parts=parts, waiting=waiting, page=page
        )
    if isinstance(v, str):  # a choice (Knob.kind): the only knobs holding a string
        choices = list(k.choices or ())
        return ChoiceKnob(
            type="choice", value=v, choices=choices, unit=k.unit, doc=k.doc, parts=parts,
            waiting=waiting, page=page,
        )  # fmt: skip
    return NumberKnob(
        type="number", value=v, min=k.min, max=k.max, unit=k.unit, doc=k.doc, parts=parts,
        waiting=waiting, page=page,
    )  # fmt: skip


def _params(knobs: dict[str, Knob]) -> Params:
    return Params({name: _knob_out(k) for name, k in knobs.items()})


def _check_knob(name: str, k: Knob, value: Any) -> KnobValue | ErrorEntry:
    """Validate one PATCH field against its knob (:meth:`Knob.check`, the one check):
    the value as the knob takes it, or the field's error entry."""
    try:
        return k.check(value)
    except ParameterError as exc:
        msg = f"{name}: expected {exc.expected}, got {echo(value)!r}"
        return error(name, exc.expected, value, msg)


@router.get("", summary="live parameters with their allowed ranges", response_model=Params)
def params(live: Knobs) -> Params:
    return _params(live.knobs())


@router.patch(
    "",
    summary="change live parameters (all or nothing)",
    dependencies=[Authorised],
    response_model=Params,
    responses=error_responses(413, 422),
)
def patch_params(body: ParamsPatch, live: Knobs) -> Params:
    # types are the request model's to check (KnobValue: a huge integer or a list never
    # reaches the knob), ranges and choices the knob's (Knob.check, one message)
    changes = body.root
    knobs = live.knobs()
    errors: list[ErrorEntry] = []
    clean: dict[str, KnobValue] = {}
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
        if name in KNOBS and name not in knobs:  # a knob, not of this pipeline's parts
            allowed, why = not_read(name, tuple(knobs))
            errors.append(error(name, allowed, value, f"{why}; expected {allowed}"))
            continue
        if name not in knobs:
            allowed = "one of " + ", ".join(knobs)
            errors.append(
                error(name, allowed, value, f"unknown parameter {echo(name)!r}; expected {allowed}")
            )
            continue
        checked = _check_knob(name, knobs[name], value)
        if isinstance(checked, dict):  # an error entry (a knob's value is never a dict)
            errors.append(checked)
        else:
            clean[name] = checked
    if errors:
        raise HTTPException(422, detail=errors)
    return _params(live.set_knobs(clean))
