"""``POST /api/control``: pause, resume, reset, speed, scenario; the monitor's inject and
relearn."""

from __future__ import annotations

from fastapi import APIRouter

from common.jsonsafe import json_safe
from server.service.deps import Authorised, Live
from server.service.schemas import Control, ControlState, error_responses

router = APIRouter(responses=error_responses())


@router.post(
    "/api/control",
    summary="pause, resume, reset, set the speed or the scenario; inject an event, relearn",
    dependencies=[Authorised],
    response_model=ControlState,
    response_model_exclude_none=True,  # scheduled, relearned: only for their action
    responses=error_responses(413, 422),
)
def control(body: Control, lp: Live) -> ControlState:
    # the value and the scenario are checked by the request model (Speed, ScenarioName),
    # as are inject's and relearn's fields; what the pipeline refuses (a source without a
    # simulator, a part already made) is a ParameterError: a 422 naming the field
    scheduled = relearned = None
    if body.action == "inject" and body.kind is not None:
        scheduled = lp.inject(body.kind, size=body.size, at_t=body.at_t, at_part=body.at_part)
    elif body.action == "relearn":
        relearned = lp.relearn(tool=body.tool, program=body.program)
    elif body.action == "pause":
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
        speed=lp.speed,
        paused=lp.paused,
        sim_t=lp.sim_t,
        scenario=lp.scenario,
        scheduled=json_safe(scheduled) if scheduled is not None else None,
        relearned=json_safe(relearned) if relearned is not None else None,
    )
