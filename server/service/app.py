"""The FastAPI application: REST, WebSocket stream, dashboard files.

Built by :func:`create_app`; the lifespan starts one :class:`~server.service.loop.LiveLoop`
thread and stops it (and tells every WebSocket client) on shutdown. Serve it with one
uvicorn worker: the simulation lives in the process (``cutwatch serve``). The routes are
in ``server.service.routes``; every 4xx answers ``{"detail": [{field, allowed, got, msg}]}``
(``server.service.http_errors``).
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
from collections.abc import AsyncIterator, Sequence
from pathlib import Path
from typing import Any

from fastapi import FastAPI, Request
from fastapi.exceptions import RequestValidationError
from fastapi.responses import JSONResponse, Response
from fastapi.routing import APIRoute
from fastapi.staticfiles import StaticFiles
from starlette.exceptions import HTTPException as StarletteHTTPException

from common.errors import ParameterError
from server.errors import CutwatchError
from server.records.store import DataStore
from server.service.analysis import Analyses
from server.service.auth import Access
from server.service.http_errors import (
    FieldError,
    SafeJSONResponse,
    echo,
    error,
    sanitise,
)
from server.service.hub import Hub
from server.service.loop import LiveLoop, checkpoint_path, loop_parts
from server.service.middleware import BodyLimit, Guard
from server.service.routes import ROUTERS
from server.service.settings import Settings, check_security

log = logging.getLogger("cutwatch.service")
WEB_DIR = Path(__file__).resolve().parents[2] / "web"
UPLOT_DIR = WEB_DIR / "node_modules" / "uplot" / "dist"


def create_app(settings: Settings | None = None) -> FastAPI:
    """Build the service.

    Parameters
    ----------
    settings
        Configuration; read from the environment (``CUTWATCH_*``) when omitted.

    Raises
    ------
    CutwatchError
        When bound to a non-loopback address without ``CUTWATCH_TOKEN``.
    """
    s = settings if settings is not None else Settings()
    check_security(s)
    _log_to_stderr()

    @contextlib.asynccontextmanager
    async def lifespan(app: FastAPI) -> AsyncIterator[None]:
        stale = app.state.store.clean_stale()  # nothing runs yet: all of it is left over
        if stale:
            log.warning(
                "removed %d temporary file(s) left by an interrupted run: %s",
                len(stale), ", ".join(stale)[:2000],
            )  # fmt: skip
        from server.service import upload_check

        # the upload checker's server process, started now (its imports take seconds)
        warming = asyncio.create_task(asyncio.to_thread(upload_check.warm))
        hub = Hub(s.client_buffer)
        hub.bind(asyncio.get_running_loop())
        parts = loop_parts(s)
        loop = LiveLoop(
            s,
            hub,
            pipeline=parts.pipeline,
            feed=parts.feed,
            estimates_out=parts.estimates_out,
            events_out=parts.events_out,
            checkpoint=checkpoint_path(s),
            history=parts.history,
        )
        app.state.hub, app.state.loop = hub, loop
        if s.viser:
            from server.service.viser_scene import VISER_HOST, StageScene

            # loopback only: browsers reach it through /viser/, behind the session
            loop.scene = StageScene(VISER_HOST, s.viser_port)
        loop.start()
        try:
            yield
        finally:
            warming.cancel()
            app.state.analyses.close()
            hub.close()
            await asyncio.to_thread(loop.stop)
            if loop.scene is not None:
                loop.scene.stop()
            if parts.history is not None:
                parts.history.close()

    app = FastAPI(
        title="cutwatch",
        version="0.1.0",
        lifespan=lifespan,
        description="Live cutting-force observers on a simulated machine tool. Every 4xx "
        'answers {"detail": [{"field", "allowed", "got", "msg"}]} (schema ErrorBody).',
    )
    app.state.settings = s
    app.state.access = Access.from_settings(s)
    app.state.store = DataStore(s.data_dir, reports=s.reports_dir)
    app.state.analyses = Analyses(app.state.store)
    app.exception_handler(RequestValidationError)(_validation_error)
    app.exception_handler(ParameterError)(_parameter_error)
    app.exception_handler(CutwatchError)(_cutwatch_error)
    app.exception_handler(StarletteHTTPException)(_http_error)
    for router in ROUTERS:
        app.include_router(router)
    if UPLOT_DIR.is_dir():
        app.mount("/vendor/uplot", StaticFiles(directory=UPLOT_DIR), name="uplot")
    if WEB_DIR.is_dir():
        app.mount("/", StaticFiles(directory=WEB_DIR, html=True), name="web")
    app.add_middleware(
        BodyLimit, limit=s.max_body_bytes, paths={"/api/uploads": s.upload_max_bytes}
    )
    app.add_middleware(Guard)  # outermost: Host, Origin, role, headers, audit
    return app


def _log_to_stderr() -> None:
    """The service's own log lines (``cutwatch.*``: the audit trail, start-up notes) on
    stderr at INFO, beside uvicorn's (which configures only its own loggers)."""
    root = logging.getLogger("cutwatch")
    if not root.handlers:
        h = logging.StreamHandler()
        h.setFormatter(logging.Formatter("%(asctime)s %(name)s %(levelname)s: %(message)s"))
        root.addHandler(h)
        root.setLevel(logging.INFO)


# ------------------------------------------------------------------ exception handlers
def _errors(status: int, items: Sequence[dict[str, Any]], **kw: Any) -> JSONResponse:
    return SafeJSONResponse({"detail": list(items)}, status_code=status, **kw)


async def _parameter_error(request: Request, exc: ParameterError) -> JSONResponse:
    # the one ParameterError class of common.errors (machine and estimators re-export it)
    return _errors(422, [error(exc.name, exc.expected, exc.got, str(exc))])


async def _cutwatch_error(request: Request, exc: CutwatchError) -> JSONResponse:
    if isinstance(exc, FieldError):
        return _errors(422, [exc.entry()])
    return _errors(422, [error("body", "a request the service can carry out", None, str(exc))])


async def _http_error(request: Request, exc: StarletteHTTPException) -> Response:
    """HTTPException (ours, with a structured detail) and the framework's 404/405."""
    if exc.status_code < 400:  # 304 and friends: no body
        return Response(status_code=exc.status_code, headers=exc.headers)
    headers = dict(exc.headers or {})
    path = request.url.path
    if isinstance(exc.detail, list):
        items = exc.detail
    elif exc.status_code == 404:
        msg = f"{exc.detail}: no route or dashboard file at {path}"
        items = [error("path", "a path listed in /openapi.json or a dashboard file", path, msg)]
    elif exc.status_code == 405:
        allowed = _methods(request) or ["GET", "HEAD"]  # otherwise a static file
        headers["Allow"] = ", ".join(allowed)
        msg = f"{exc.detail}: {request.method} {path}; allowed: {', '.join(allowed)}"
        items = [error("method", "one of " + ", ".join(allowed), request.method, msg)]
    elif exc.status_code == 400 and exc.detail == "There was an error parsing the body":
        # FastAPI's answer when json.loads itself fails (nesting past the parser's
        # recursion limit, an integer of more than 4,300 digits)
        rule = (
            "a JSON document the parser accepts (not nested past ~1,000 levels, "
            "integers under 4,300 digits)"
        )
        items = [error("body", rule, None, "the body could not be parsed as JSON: " + rule)]
    else:
        items = [error("request", "see msg", None, str(exc.detail))]
    return _errors(exc.status_code, items, headers=headers or None)


def _methods(request: Request) -> list[str]:
    """The methods the API routes accept at this request's path (sorted)."""
    out: set[str] = set()
    for router in ROUTERS:
        for route in router.routes:
            if isinstance(route, APIRoute) and route.path_regex.match(request.url.path):
                out |= route.methods or set()
    return sorted(out)


# pydantic error type -> what the field allows (when the message alone does not say)
_ALLOWED = {
    "missing": "a value (the field is required)",
    "json_invalid": "a JSON object",
    "dict_type": "a JSON object",
    "model_type": "a JSON object",
    "model_attributes_type": "a JSON object",
}


#: error types of the request models' own validators (server.service.schemas, settings)
_OURS = frozenset({"speed", "scenario", "knob_value", "missing_for_action", "refused"})


async def _validation_error(request: Request, exc: RequestValidationError) -> JSONResponse:
    """FastAPI's 422, one entry per refused field, inputs made JSON-safe (a body of
    Infinity or NaN would otherwise fail to serialise and turn the 422 into a 500)."""
    return _errors(422, [_validation_item(request, e) for e in exc.errors()])


def _validation_item(request: Request, e: Any) -> dict[str, Any]:
    loc = list(e.get("loc") or ["body"])
    kind = str(e.get("type", ""))
    ctx = e.get("ctx") or {}
    raw = str(e.get("msg", ""))
    if kind == "json_invalid":
        field = str(loc[0])
        got: Any = None
        raw = f"{raw} at character {loc[1]}: {ctx.get('error', '')}" if len(loc) > 1 else raw
    else:
        parts = [f"[{p}]" if isinstance(p, int) else f".{p}" for p in loc[1:]]
        field = str(ctx.get("field") or "".join(parts).lstrip(".") or loc[0])
        got = None if kind == "missing" else sanitise(ctx.get("got", e.get("input")))
    if kind == "literal_error":
        allowed = f"one of {ctx.get('expected', '')}"
    elif kind == "extra_forbidden":
        names = _body_fields(request)
        allowed = "only " + ", ".join(names) if names else "no extra fields"
    elif kind in _ALLOWED:
        allowed = _ALLOWED[kind]
    else:
        allowed = raw.removeprefix("Input should be ").removeprefix("expected ")
    msg = f"{field}: {raw}"
    if kind in _OURS:  # the request models' own checks: one sentence, the value found
        msg = f"{field}: expected {allowed}, got {echo(got)!r}"
    item = error(field, allowed, None, msg)
    item["got"] = got  # the input as sent (bounded), a structure kept a structure
    return item


def _body_fields(request: Request) -> list[str]:
    """Field names of the route's request body model (for 'extra field' errors)."""
    route = request.scope.get("route")
    body = getattr(route, "body_field", None)
    model = getattr(getattr(body, "field_info", None), "annotation", None)
    fields = getattr(model, "model_fields", None)
    return list(fields) if isinstance(fields, dict) else []
