"""``POST /api/control``: pause, resume, reset, speed, scenario; the monitor's inject and
relearn."""

from __future__ import annotations

from fastapi import APIRouter

from common.jsonsafe import json_safe
from server.service.deps import Authorised, Controls, Monitor, Relearned, Scheduled
from server.service.schemas import (
    Control,
    ControlState,
    Inject,
    Pause,
    Relearn,
    Reset,
    Resume,
    SetScenario,
    SetSpeed,
    error_responses,
)

router = APIRouter(prefix="/api/control", tags=["control"], responses=error_responses())


@router.post(
    "",
    summary="pause, resume, reset, set the speed or the scenario; inject an event, relearn",
    dependencies=[Authorised],
    response_model=ControlState,
    response_model_exclude_none=True,  # scheduled, relearned: only for their action
    responses=error_responses(413, 422),
)
def control(body: Control, pace: Controls, monitor: Monitor) -> ControlState:
    # the value and the scenario are checked by the request model (Speed, ScenarioName),
    # as are inject's and relearn's fields; what the pipeline refuses (a source without a
    # simulator, a part already made) is a ParameterError: a 422 naming the field
    scheduled: Scheduled | None = None
    relearned: Relearned | None = None
    match body:
        case Inject(kind=kind, size=size, at_t=at_t, at_part=at_part):
            scheduled = monitor.inject(kind, size=size, at_t=at_t, at_part=at_part)
        case Relearn(tool=tool, program=program):
            relearned = monitor.relearn(tool=tool, program=program)
        case Pause():
            pace.pause()
        case Resume():
            pace.resume()
        case Reset():
            pace.reset()
        case SetScenario(scenario=name):
            pace.set_scenario(name)
        case SetSpeed(value=value):
            pace.set_speed(value)
    return ControlState(
        speed=pace.speed,
        paused=pace.paused,
        sim_t=pace.sim_t,
        scenario=pace.scenario,
        scheduled=json_safe(scheduled) if scheduled is not None else None,
        relearned=json_safe(relearned) if relearned is not None else None,
    )
