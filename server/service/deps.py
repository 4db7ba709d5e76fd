"""FastAPI dependencies: the live loop and the narrow views of it the routes take, the
settings, the data store, the operator role.

A route takes what it uses, not the whole loop: each view below is a ``Protocol`` of the
loop's methods one concern needs (the pace, the monitor's actions, the knobs, the observer
effects, the recordings), handed out by a dependency built on :func:`live_loop`, so
overriding :func:`live_loop` (the in-process tests) overrides every view, and mypy checks
both that the loop provides each view and that a route uses nothing else of it.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from typing import Annotated, Any, Protocol

from fastapi import Depends, HTTPException, Request

from estimators.observer_effects import ObserverEffect
from server.pipeline.knobs import Knob, KnobValue
from server.pipeline.live_pipeline import LivePipeline
from server.pipeline.process_part import Relearned
from server.pipeline.sources import Scheduled
from server.records.data_areas import DataStore
from server.service.auth import operator
from server.service.http_errors import error
from server.service.loop import LiveLoop
from server.service.recording import Recording, RecordingSidecar
from server.service.settings import Settings


def live_loop(request: Request) -> LiveLoop:
    """The app's :class:`LiveLoop` (started by the lifespan)."""
    loop: LiveLoop = request.app.state.loop
    return loop


def settings(request: Request) -> Settings:
    """The app's :class:`Settings`."""
    s: Settings = request.app.state.settings
    return s


def data_store(request: Request) -> DataStore:
    """The app's :class:`DataStore` (recordings, uploads, reports by name)."""
    st: DataStore = request.app.state.store
    return st


Live = Annotated[LiveLoop, Depends(live_loop)]
Config = Annotated[Settings, Depends(settings)]
Store = Annotated[DataStore, Depends(data_store)]


# ---------------------------------------------------------------- the loop's views
class PaceControl(Protocol):
    """The loop's pace: pause, resume, reset, speed, scenario (``POST /api/control``)."""

    @property
    def speed(self) -> float: ...
    @property
    def paused(self) -> bool: ...
    @property
    def sim_t(self) -> float: ...
    @property
    def scenario(self) -> str: ...
    def pause(self) -> None: ...
    def resume(self) -> None: ...
    def reset(self) -> None: ...
    def set_speed(self, speed: float) -> None: ...
    def set_scenario(self, name: str) -> None: ...


class MonitorActions(Protocol):
    """The process monitor's actions: an event injected, the limits taught again."""

    def inject(
        self,
        kind: str,
        size: float | None = None,
        at_t: float | None = None,
        at_part: int | None = None,
    ) -> Scheduled: ...
    def relearn(self, tool: int | None = None, program: str | None = None) -> Relearned: ...


class KnobControl(Protocol):
    """The live knobs: read them, change them all or nothing (``/api/params``)."""

    def knobs(self) -> dict[str, Knob]: ...
    def set_knobs(self, changes: Mapping[str, KnobValue]) -> dict[str, Knob]: ...


class EffectControl(Protocol):
    """The live observer's identified effects, and a replayed log's pipeline."""

    def observer_effects(self) -> tuple[ObserverEffect, ...]: ...
    def set_observer_effects(
        self, effects: tuple[ObserverEffect, ...]
    ) -> tuple[tuple[ObserverEffect, ...], float]: ...
    def set_pipeline(self, pipe: LivePipeline) -> None: ...
    def axis_effects(self) -> tuple[dict[str, list[str]], float]: ...
    def set_axis_effects(self, effects: Mapping[str, tuple[Any, ...]]) -> float: ...


class RecordingControl(Protocol):
    """Recording the live source: the one in progress, start, end, and whether anything
    runs to record (``/api/record``, ``/api/records``)."""

    @property
    def recording(self) -> Recording | None: ...
    @property
    def running(self) -> bool: ...
    @property
    def finished(self) -> bool: ...
    @property
    def paused(self) -> bool: ...
    @property
    def error(self) -> str | None: ...
    def start_recording(
        self, make: Callable[[RecordingSidecar], Recording], refuse: Callable[[], None] = ...
    ) -> Recording: ...
    def end_recording(self, reason: str) -> Recording | None: ...


def pace_control(lp: Live) -> PaceControl:
    return lp


def monitor_actions(lp: Live) -> MonitorActions:
    return lp


def knob_control(lp: Live) -> KnobControl:
    return lp


def effect_control(lp: Live) -> EffectControl:
    return lp


def recording_control(lp: Live) -> RecordingControl:
    return lp


Controls = Annotated[PaceControl, Depends(pace_control)]
Monitor = Annotated[MonitorActions, Depends(monitor_actions)]
Knobs = Annotated[KnobControl, Depends(knob_control)]
LiveEffects = Annotated[EffectControl, Depends(effect_control)]
Recordings = Annotated[RecordingControl, Depends(recording_control)]


def conflict(field: str, allowed: str, got: object, msg: str) -> HTTPException:
    """A 409 (the request does not fit the service's state) in the one error shape."""
    return HTTPException(409, detail=[error(field, allowed, got, msg)])


#: route dependency of every state-changing endpoint: the operator role
#: (:func:`server.service.auth.operator`; the middleware has checked it already, the
#: dependency keeps it on the route and in the OpenAPI document)
Authorised = Depends(operator)
