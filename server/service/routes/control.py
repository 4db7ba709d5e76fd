"""``POST /api/control``: pause, resume, reset, speed, scenario."""

from __future__ import annotations

import math

from fastapi import APIRouter, HTTPException

from server.pipeline.live_pipeline import SCENARIOS
from server.service.deps import Authorised, Live
from server.service.errors import _json_safe, error
from server.service.schemas import Control, ControlState, error_responses
from server.service.settings import MAX_SPEED

router = APIRouter(responses=error_responses())


@router.post(
    "/api/control",
    summary="pause, resume, reset, or set the speed",
    dependencies=[Authorised],
    response_model=ControlState,
    responses=error_responses(401, 413, 422),
)
def control(body: Control, lp: Live) -> ControlState:
    if body.action == "pause":
        lp.pause()
    elif body.action == "resume":
        lp.resume()
    elif body.action == "reset":
        lp.reset()
    elif body.action == "scenario":
        if body.scenario not in SCENARIOS:
            allowed = "one of " + ", ".join(SCENARIOS)
            raise HTTPException(
                422,
                detail=[
                    error(
                        "scenario",
                        allowed,
                        body.scenario,
                        f"scenario: expected {allowed}, got {body.scenario!r}",
                    )
                ],
            )
        lp.set_scenario(body.scenario)
    else:
        v = body.value
        if v is None or not math.isfinite(v) or not 0.0 <= v <= MAX_SPEED:
            raise HTTPException(
                422,
                detail=[
                    error(
                        "value",
                        f"a number in [0, {MAX_SPEED:g}]",
                        v,
                        f"speed: expected a number in [0, {MAX_SPEED:g}], got {_json_safe(v)!r}",
                    )
                ],
            )
        lp.set_speed(v)
    return ControlState(speed=lp.speed, paused=lp.paused, sim_t=lp.sim_t, scenario=lp.scenario)
