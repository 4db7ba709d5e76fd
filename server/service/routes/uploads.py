"""Logs sent to the service: ``POST /api/uploads?name=NAME`` (the raw file as the body)
and ``GET /api/uploads``.

One file per request, into the uploads area: a log (``.csv``, ``.mat``) or its sidecar
(``.json``, the same stem; send it first, a CSV log needs its units). The body streams
to a temporary file; its size limit (``CUTWATCH_UPLOAD_MAX_MB``) is enforced while it
arrives (413, nothing kept). A log then runs the checks of the command line's log loader
(:func:`server.records.measured_log.load_log`, with its sidecar when there is one); a
log that fails them is removed and the answer is the loader's message (422). A sidecar
must be a JSON object; when its log is there already, the pair is checked again and a
sidecar that makes it fail is removed.
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import os
import tempfile
from pathlib import Path

from fastapi import APIRouter, HTTPException, Query, Request
from fastapi.responses import Response
from starlette.requests import ClientDisconnect

from server.errors import CutwatchError
from server.records.measured_log import MeasuredLog, load_log
from server.records.store import DataStore, check_name
from server.service.datafiles import scrub
from server.service.deps import Authorised, Config, Store, conflict
from server.service.http_errors import FieldError, error
from server.service.schemas import UploadInfo, Uploads, error_responses

router = APIRouter(responses=error_responses())

SUFFIXES = (".csv", ".mat", ".json")
_NAME_RULE = (
    "a plain file name (1-128 of A-Z a-z 0-9 _ . - starting with a letter or digit) "
    "ending in .csv, .mat or .json"
)


def _check(path: Path) -> MeasuredLog:
    return load_log(path)


def _info(p: Path, log: MeasuredLog | None = None) -> UploadInfo:
    is_log = p.suffix.lower() != ".json"
    return UploadInfo(
        name=p.name,
        bytes=p.stat().st_size,
        kind="log" if is_log else "sidecar",
        checked=True if log is not None else None,
        samples=None if log is None else len(log["t"]),
        sample_time=None if log is None else log.sample_time,
        log_kind=None if log is None else log.kind,
    )


def _log_of(st: DataStore, sidecar: Path) -> Path | None:
    """The CSV log beside a sidecar (a .mat log has no sidecar)."""
    p = sidecar.with_suffix(".csv")
    return p if p.is_file() else None


@router.post(
    "/api/uploads",
    summary="upload a measured log or its sidecar (the raw file as the body)",
    dependencies=[Authorised],
    response_model=UploadInfo,
    responses=error_responses(409, 413, 422),
    openapi_extra={
        "requestBody": {
            "required": True,
            "content": {"application/octet-stream": {"schema": {"type": "string"}}},
        }
    },
)
async def upload(
    request: Request,
    st: Store,
    s: Config,
    name: str = Query(..., max_length=128, description=_NAME_RULE),
) -> UploadInfo | Response:
    if not check_name(name) or Path(name).suffix.lower() not in SUFFIXES:
        raise FieldError("name", _NAME_RULE, name, f"name {name!r}: expected {_NAME_RULE}")
    final = st.new_path("uploads", name)
    if final.exists():
        raise conflict("name", "a name not taken", name, f"upload {name!r} exists already")
    limit = s.upload_max_bytes
    fd, tmp = tempfile.mkstemp(prefix=f".{name}.", suffix=".tmp", dir=final.parent)
    size = 0
    try:
        with os.fdopen(fd, "wb") as fh:
            async for chunk in request.stream():
                size += len(chunk)
                if size > limit:  # the middleware answers first; this guards without it
                    msg = f"request body larger than {limit} bytes"
                    item = error("body", f"at most {limit} bytes", size, msg)
                    raise HTTPException(413, detail=[item])
                fh.write(chunk)
    except ClientDisconnect:  # over the limit (the 413 went out) or the client left
        _unlink(tmp)
        return Response(status_code=413)
    except BaseException:
        _unlink(tmp)
        raise
    if size == 0:
        _unlink(tmp)
        raise FieldError("body", "the file's bytes", 0, "empty body: expected the file's bytes")
    if final.exists():
        _unlink(tmp)
        raise conflict("name", "a name not taken", name, f"upload {name!r} exists already")
    os.replace(tmp, final)
    if final.suffix.lower() == ".json":
        try:
            side = json.loads(final.read_bytes())
            if not isinstance(side, dict):
                raise ValueError(f"expected a JSON object, found {type(side).__name__}")
        except (ValueError, UnicodeDecodeError) as exc:
            _unlink(final)
            raise FieldError(
                "body", "a JSON object (the log's sidecar)", None, f"{name}: not a sidecar: {exc}"
            ) from None
        log_path = _log_of(st, final)
        if log_path is None:
            return _info(final)
        final, name = log_path, log_path.name  # the pair is checked below
        undo = final.with_suffix(".json")
    else:
        undo = final
    try:
        log = await asyncio.to_thread(_check, final)
    except CutwatchError as exc:
        _unlink(undo)
        raise FieldError(
            "body",
            "a measured log passing the log loader's checks",
            undo.name,
            f"{scrub(str(exc), final, name)} (the upload {undo.name!r} was removed)",
        ) from None
    return _info(final, log)


def _unlink(p: str | Path) -> None:
    with contextlib.suppress(OSError):
        os.unlink(p)


@router.get("/api/uploads", summary="uploaded logs and sidecars", response_model=Uploads)
def list_uploads(st: Store) -> Uploads:
    files = [p for p in st.list("uploads") if p.is_file() and p.suffix.lower() in SUFFIXES]
    return Uploads(uploads=[_info(p) for p in files])
