"""Recording the live source: ``POST /api/record``, ``GET /api/records`` and the files.

A recording is a measured log in the design's format (docs/design.md: CSV + JSON sidecar)
in the recordings area of the data directory; it is what the residual loop reads next
(``POST /api/analyses``, ``cutwatch residual``).
"""

from __future__ import annotations

import asyncio
import json
import time
from pathlib import Path

from fastapi import APIRouter, HTTPException
from fastapi.responses import FileResponse

from server.records.data_areas import DataStore, NotFound, check_name
from server.service.deps import (
    Authorised,
    Config,
    RecordingControl,
    Recordings,
    Store,
    conflict,
)
from server.service.http_errors import FieldError, error
from server.service.recording import Recording, default_name
from server.service.schemas import RecordBody, RecordInfo, Records, RecordState, error_responses

router = APIRouter(prefix="/api", tags=["recordings"], responses=error_responses())

_NAME_RULE = "a plain name: 1-128 of A-Z a-z 0-9 _ . - starting with a letter or digit, '.csv'"


def not_found(exc: NotFound) -> HTTPException:
    """A 404 in the one error shape; the same answer whatever lies on the host."""
    allowed = f"the name of one of the service's {exc.area}"
    return HTTPException(404, detail=[error("name", allowed, exc.name, str(exc))])


def nothing_runs(lp: RecordingControl) -> str | None:
    """Why nothing runs to record (None: the loop runs a source)."""
    if not lp.running:
        why = f" ({lp.error})" if lp.error else ""
        return f"nothing runs: the live loop has stopped{why}"
    if lp.finished:
        return "nothing runs: the replayed log has ended (start a scenario or a replay)"
    if lp.paused:
        return "nothing runs: the loop is paused (resume it: POST /api/control)"
    return None


def _record_name(name: str | None) -> str:
    n = default_name(time.time()) if name is None else name.strip()
    if "." not in n:
        n += ".csv"
    if not (check_name(n) and n.endswith(".csv")):
        raise FieldError("name", _NAME_RULE, name, f"name {name!r}: expected {_NAME_RULE}")
    return n


@router.post(
    "/record",
    summary="start or stop recording what the live source delivers",
    dependencies=[Authorised],
    response_model=RecordState,
    responses=error_responses(409, 413, 422),
)
async def record(body: RecordBody, lp: Recordings, s: Config, st: Store) -> RecordState:
    if body.action == "stop":
        if body.name is not None:
            raise FieldError("name", "no name with action 'stop'", body.name, "stop takes no name")
        rec = lp.recording
        if rec is None or not rec.active:
            ended = "" if rec is None else rec.recorder.end_reason or rec.recorder.limit_reason
            why = f" (the last recording ended: {ended})" if ended else ""
            raise conflict("action", "'start' first", "stop", f"not recording{why}")
        lp.end_recording("stopped")
        done = await asyncio.to_thread(rec.wait)
        return RecordState(recording=RecordInfo.model_validate(done))
    name = _record_name(body.name)
    path = st.new_path("recordings", name)

    def refuse() -> None:
        idle = nothing_runs(lp)
        if idle is not None:
            raise conflict("action", "'start' while the loop runs a source", "start", idle)
        if lp.recording is not None and lp.recording.active:
            raise conflict(
                "action",
                "'stop' first",
                "start",
                f"already recording {lp.recording.name!r}: stop it first",
            )
        if path.exists() or path.with_suffix(".json").exists():
            raise conflict("name", "a name not taken", name, f"recording {name!r} exists already")

    started = lp.start_recording(
        lambda side: Recording(
            path, side, max_bytes=s.record_max_mb * 1e6, max_seconds=s.record_max_minutes * 60.0
        ),
        refuse,
    )
    return RecordState(recording=RecordInfo.model_validate(started.summary()))


def recordings(st: DataStore, lp: RecordingControl) -> list[RecordInfo]:
    """The recording in progress (if any) and those on disk, newest first."""
    out: list[RecordInfo] = []
    rec = lp.recording
    if rec is not None and rec.active:
        out.append(RecordInfo.model_validate(rec.summary()))
    files = sorted(st.list("recordings", "*.csv"), key=lambda p: p.stat().st_mtime, reverse=True)
    out.extend(_on_disk(p) for p in files if p.name not in {o.name for o in out})
    return out


def _on_disk(p: Path) -> RecordInfo:
    """A recording on disk: its size, and its samples, duration and end from its sidecar
    (``end`` says so when the sidecar cannot be read)."""
    size = p.stat().st_size
    try:
        side = json.loads(p.with_suffix(".json").read_text())
        n = int(side["recording"]["samples"])
        seconds = n * float(side["sample_time"])
        end = side["recording"]["end"]
    except (OSError, ValueError, KeyError, TypeError):
        return RecordInfo(name=p.name, samples=None, seconds=None, bytes=size, active=False,
                          end="no readable sidecar")  # fmt: skip
    return RecordInfo(name=p.name, samples=n, seconds=seconds, bytes=size, active=False, end=end)


@router.get("/records", summary="recordings (in progress and on disk)", response_model=Records)
def list_records(lp: Recordings, st: Store) -> Records:
    return Records(records=recordings(st, lp))


def _recording_csv(st: DataStore, name: str) -> Path:
    try:
        p = st.resolve("recordings", name, suffixes=(".csv",))
    except NotFound as exc:
        raise not_found(exc) from None
    if p.suffix != ".csv" or not p.is_file():
        raise not_found(NotFound("recordings", name))
    return p


@router.get(
    "/records/{name}",
    summary="download a recording (its CSV)",
    response_class=FileResponse,
    responses={
        200: {"description": "the CSV", "content": {"text/csv": {"schema": {"type": "string"}}}},
        **error_responses(404, json_route=False),
    },
)
def get_record(name: str, st: Store) -> FileResponse:
    p = _recording_csv(st, name)
    return FileResponse(p, media_type="text/csv", filename=p.name)


@router.get(
    "/records/{name}/sidecar",
    summary="a recording's JSON sidecar",
    response_class=FileResponse,
    responses={
        200: {
            "description": "the sidecar (sample_time, units, kind, nominal, recording...)",
            "content": {"application/json": {"schema": {"type": "object"}}},
        },
        **error_responses(404, json_route=False),
    },
)
def get_record_sidecar(name: str, st: Store) -> FileResponse:
    p = _recording_csv(st, name).with_suffix(".json")
    if not p.is_file():
        raise not_found(NotFound("recordings", name))
    return FileResponse(p, media_type="application/json", filename=p.name)
