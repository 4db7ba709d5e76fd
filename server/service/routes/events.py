"""The kept history over REST: ``GET /api/events``, ``POST /api/events/{id}/ack``,
``GET /api/tool-life``; ``POST /api/tool-life/vb``: the VB measured at a tool change,
which calibrates the live wear map of a machine with a spindle's power (issue 35 item 7).

Reads are the viewer's, the acknowledgement the operator's. The store
(:mod:`server.records.history`) is the loop's (``LiveLoop.history``); its calls run in a
worker thread, so a write's fsync never holds up the event loop. An acknowledgement is
committed before it is answered; it is then announced to every stream client
(``LiveLoop.announce_event``).
"""

from __future__ import annotations

import asyncio
import math
from typing import Annotated

from fastapi import APIRouter, Depends, HTTPException, Path, Query

from common.event_kinds import EventKind
from server.records.history import HistoryStore
from server.records.history.store import MAX_LIMIT, EventRow
from server.records.monitor_events import EventRecord, event_record
from server.service.auth import operator
from server.service.deps import Live, conflict
from server.service.http_errors import error
from server.service.loop import LiveLoop
from server.service.schemas import (
    AckBody,
    HistoryEvent,
    HistoryEvents,
    ToolLife,
    ToolLives,
    ToolVb,
    ToolVbLabel,
    error_responses,
)

router = APIRouter(responses=error_responses())

Limit = Annotated[int, Query(ge=1, le=MAX_LIMIT, description="items per page")]
Offset = Annotated[int, Query(ge=0, le=10**9, description="items to skip (newest first)")]
Tool = Annotated[int | None, Query(ge=0, le=10**6, description="only this tool number")]
#: an event id as the service makes them (32 hex digits; other stores may use up to 64)
EVENT_ID = r"^[A-Za-z0-9_.:-]{1,64}$"


def history_of(lp: LiveLoop) -> HistoryStore:
    """The loop's history, or a 409 saying why there is none to query."""
    h = lp.history
    if not isinstance(h, HistoryStore):
        raise conflict(
            "history",
            "a service keeping its history (CUTWATCH_HISTORY_URL unset or a database URL)",
            "none",
            "this service keeps no history (CUTWATCH_HISTORY_URL=none)",
        )
    return h


def _wall(name: str, v: float | None) -> float | None:
    if v is not None and not math.isfinite(v):
        raise HTTPException(
            422,
            detail=[error(name, "a finite time [unix s]", v, f"{name}: expected a finite "
                          f"time [unix s], got {v!r}")],
        )  # fmt: skip
    return v


@router.get(
    "/api/events",
    summary="the kept monitor events, newest first, filtered and paged",
    response_model=HistoryEvents,
    responses=error_responses(409, 422),
)
async def list_events(
    lp: Live,
    kind: Annotated[EventKind | None, Query(description="only events of this kind")] = None,
    tool: Tool = None,
    acked: Annotated[bool | None, Query(description="only acknowledged (true) or not")] = None,
    since: Annotated[float | None, Query(description="received at or after [unix s]")] = None,
    until: Annotated[float | None, Query(description="received before [unix s]")] = None,
    limit: Limit = 100,
    offset: Offset = 0,
) -> HistoryEvents:
    h = history_of(lp)
    total, items = await asyncio.to_thread(
        h.events,
        kind=kind,
        tool=tool,
        acked=acked,
        since=_wall("since", since),
        until=_wall("until", until),
        limit=limit,
        offset=offset,
    )
    return HistoryEvents(total=total, items=[HistoryEvent.model_validate(e) for e in items])


@router.post(
    "/api/events/{event_id}/ack",
    summary="acknowledge an event (idempotent: again, it answers the first acknowledgement)",
    response_model=HistoryEvent,
    responses=error_responses(404, 409, 413, 422),
)
async def acknowledge(
    lp: Live,
    role: Annotated[str, Depends(operator)],
    event_id: Annotated[str, Path(pattern=EVENT_ID, description="the event's id")],
    body: AckBody | None = None,
) -> HistoryEvent:
    h = history_of(lp)
    by = body.by if body is not None and body.by is not None else role
    ev = await asyncio.to_thread(h.acknowledged, event_id, by)
    if ev is None:
        allowed = "the id of an event in the history (GET /api/events)"
        msg = f"no event with id {event_id!r} in the history"
        raise HTTPException(404, detail=[error("event_id", allowed, event_id, msg)])
    announce = getattr(lp, "announce_event", None)  # the stream's (when it has it)
    if announce is not None:
        announce(_stream_event(ev))
    return HistoryEvent.model_validate(ev)


def _stream_event(ev: EventRow) -> EventRecord:
    """The event as the stream carries it (without the history's received time)."""
    return event_record(ev)


@router.get(
    "/api/tool-life",
    summary="the tools changed (start, end, wear at the change, cause), newest first",
    response_model=ToolLives,
    responses=error_responses(409, 422),
)
async def tool_life(
    lp: Live, tool: Tool = None, limit: Limit = 100, offset: Offset = 0
) -> ToolLives:
    h = history_of(lp)
    total, items = await asyncio.to_thread(h.tool_life, tool=tool, limit=limit, offset=offset)
    return ToolLives(total=total, items=[ToolLife.model_validate(r) for r in items])


@router.post(
    "/api/tool-life/vb",
    summary="enter the flank wear measured on a tool at its change: it labels the tool's "
    "latest ended life and refits that tool's wear map (the machine's own labelled lives)",
    response_model=ToolVbLabel,
    responses=error_responses(413, 422),
    tags=["tool-life"],
)
async def tool_vb(lp: Live, role: Annotated[str, Depends(operator)], body: ToolVb) -> ToolVbLabel:
    # a pipeline without the wear part, a tool with no ended life, a VB out of range: a
    # ParameterError, answered 422 naming the field
    out = await asyncio.to_thread(lp.label_tool_wear, body.tool, body.vb_mm)
    return ToolVbLabel.model_validate(out)
