"""Logs sent to the service: ``POST /api/uploads?name=NAME`` (the raw file as the body)
and ``GET /api/uploads``.

One file per request: a log (``.csv``, ``.mat``) or its sidecar (``.json``, the same
stem; send it first, a CSV log needs its units). The body streams into a private
quarantine directory (``DataStore.quarantine``), its size bounded while it arrives
(``CUTWATCH_UPLOAD_MAX_MB``: 413, nothing kept). It is then checked in a child process
with a memory limit (:mod:`server.service.upload_check`: a CSV's rows and columns, a
``.mat``'s expanded size from its headers, then the log loader's checks, with the
sidecar beside it when there is one; a sidecar alone: a JSON object of the right types,
and with its log the pair). Only a file that passes is published into the uploads area,
by a link that never replaces an existing name; until then no listing shows it and no
name reaches it. A refused file is removed and the answer names why (422).
"""

from __future__ import annotations

import os
import shutil
from pathlib import Path

from fastapi import APIRouter, HTTPException, Query, Request
from fastapi.responses import Response
from starlette.requests import ClientDisconnect

from server.records.data_areas import DataStore, check_name
from server.service.deps import Authorised, Config, Store, conflict
from server.service.http_errors import FieldError, error
from server.service.schemas import UploadInfo, Uploads, error_responses
from server.service.settings import Settings
from server.service.upload_check import CheckAnswer, Limits, LogFacts, run_check

router = APIRouter(prefix="/api/uploads", tags=["uploads"], responses=error_responses())

SUFFIXES = (".csv", ".mat", ".json")
_NAME_RULE = (
    "a plain file name (1-128 of A-Z a-z 0-9 _ . - starting with a letter or digit) "
    "ending in .csv, .mat or .json"
)


def limits(s: Settings) -> Limits:
    """The bounds of an upload's check, from the settings."""
    return Limits(
        expanded_bytes=s.upload_max_bytes,
        rows=s.upload_max_rows,
        columns=s.upload_max_columns,
        memory_mb=s.upload_check_mb,
        timeout_s=s.upload_check_s,
    )


def _info(p: Path, checked: CheckAnswer | None = None) -> UploadInfo:
    is_log = p.suffix.lower() != ".json"
    c: LogFacts = checked if checked is not None and is_log else {}
    return UploadInfo(
        name=p.name,
        bytes=p.stat().st_size,
        kind="log" if is_log else "sidecar",
        checked=True if c else None,
        samples=c.get("samples"),
        sample_time=c.get("sample_time"),
        log_kind=c.get("log_kind"),
    )


@router.post(
    "",
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
    qdir = st.quarantine()
    try:
        size = await _receive(request, qdir / name, s.upload_max_bytes)
        if size is None:  # over the limit (the 413 went out) or the client left
            return Response(status_code=413)
        if size == 0:
            raise FieldError("body", "the file's bytes", 0, "empty body: expected the file's bytes")
        checked = await _check(st, qdir, name, s)
        try:  # publish: a link never replaces a file of that name (a race: 409)
            _publish(qdir / name, final)
        except FileExistsError:
            raise conflict(
                "name", "a name not taken", name, f"upload {name!r} exists already"
            ) from None
        return _info(final, checked)
    finally:
        shutil.rmtree(qdir, ignore_errors=True)


def _publish(src: Path, dst: Path) -> None:
    """Move ``src`` to ``dst`` at once, never over an existing file (FileExistsError):
    a hard link, or (a file system without links) a rename once the name is seen free."""
    try:
        os.link(src, dst)
    except FileExistsError:
        raise
    except OSError:
        if dst.exists():
            raise FileExistsError(dst.name) from None
        os.rename(src, dst)


async def _receive(request: Request, path: Path, limit: int) -> int | None:
    """Stream the body into ``path``; its size, or None when the client left."""
    size = 0
    try:
        with path.open("wb") as fh:
            async for chunk in request.stream():
                size += len(chunk)
                if size > limit:  # the middleware answers first; this guards without it
                    msg = f"request body larger than {limit} bytes"
                    raise HTTPException(
                        413, detail=[error("body", f"at most {limit} bytes", size, msg)]
                    )
                fh.write(chunk)
    except ClientDisconnect:
        return None
    return size


async def _check(st: DataStore, qdir: Path, name: str, s: Settings) -> CheckAnswer:
    """Check the quarantined ``qdir/name`` with its published companions linked beside
    it (a log's sidecar; a sidecar's logs, each checked with it); a refusal is a
    :class:`FieldError`."""
    stem, suffix = Path(name).stem, Path(name).suffix.lower()
    companions = (".csv", ".mat") if suffix == ".json" else (".json",)
    logs = []
    for c in companions:
        other = st.area("uploads") / (stem + c)
        if other.is_file():
            try:
                os.link(other, qdir / other.name)
            except OSError:  # a file system without hard links
                shutil.copyfile(other, qdir / other.name)
            logs.append(qdir / other.name)
    if suffix != ".json":
        checks = [(qdir / name, "log")]
    else:  # the pair is checked through its logs; a sidecar alone by itself
        checks = [(p, "log") for p in logs] or [(qdir / name, "sidecar")]
    answer: CheckAnswer = {"ok": True}
    for target, what in checks:
        answer = await run_check(target, what, limits(s))
        if not answer.get("ok"):
            break
    if answer.get("ok"):
        return answer
    allowed = "a JSON object (the log's sidecar)" if suffix == ".json" else (
        "a measured log passing the log loader's checks"
    )  # fmt: skip
    msg = f"{answer.get('error', 'refused')} (the upload {name!r} was removed)"
    raise FieldError("body", allowed, name, msg)


@router.get("", summary="uploaded logs and sidecars", response_model=Uploads)
def list_uploads(st: Store) -> Uploads:
    files = [p for p in st.list("uploads") if p.is_file() and p.suffix.lower() in SUFFIXES]
    return Uploads(uploads=[_info(p) for p in files])
