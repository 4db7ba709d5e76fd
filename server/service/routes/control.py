"""``POST /api/control``: pause, resume, reset, speed, scenario."""

from __future__ import annotations

from fastapi import APIRouter

from server.service.deps import Authorised, Live
from server.service.schemas import Control, ControlState, error_responses

router = APIRouter(responses=error_responses())


@router.post(
    "/api/control",
    summary="pause, resume, reset, or set the speed",
    dependencies=[Authorised],
    response_model=ControlState,
    responses=error_responses(413, 422),
)
def control(body: Control, lp: Live) -> ControlState:
    # the value and the scenario are checked by the request model (Speed, ScenarioName)
    if body.action == "pause":
        lp.pause()
    elif body.action == "resume":
        lp.resume()
    elif body.action == "reset":
        lp.reset()
    elif body.action == "scenario" and body.scenario is not None:
        lp.set_scenario(body.scenario)
    elif body.value is not None:
        lp.set_speed(body.value)
    return ControlState(
        speed=lp.speed, paused=lp.paused, sim_t=lp.pipeline.t, scenario=lp.pipeline.scenario
    )
