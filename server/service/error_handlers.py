"""The exception handlers that give every 4xx of every process the one error body.

:func:`install` registers them on an app (the service's, the fleet page's, a worker's:
``server.service.front.protect`` does it): FastAPI's validation errors (422, one entry
per refused field, inputs made JSON-safe), ``ParameterError`` and ``CutwatchError`` (422),
and Starlette's ``HTTPException`` (ours with a structured detail; the framework's 404 and
405, naming the path or the methods allowed) all answer
``{"detail": [{field, allowed, got, msg}]}`` (``server.service.http_errors``).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

from fastapi import FastAPI, Request
from fastapi.exceptions import RequestValidationError
from fastapi.responses import JSONResponse, Response
from starlette.exceptions import HTTPException as StarletteHTTPException
from starlette.routing import Match, Mount

from common.errors import ParameterError
from server.errors import CutwatchError
from server.service.http_errors import FieldError, SafeJSONResponse, echo, error, sanitise


def install(app: FastAPI) -> None:
    """Register the handlers on ``app``."""
    app.exception_handler(RequestValidationError)(_validation_error)
    app.exception_handler(ParameterError)(_parameter_error)
    app.exception_handler(CutwatchError)(_cutwatch_error)
    app.exception_handler(StarletteHTTPException)(_http_error)


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


#: the methods a 405 may name
METHODS = ("DELETE", "GET", "HEAD", "PATCH", "POST", "PUT")


def _methods(request: Request) -> list[str]:
    """The methods the app's routes accept at this request's path (sorted), asked of
    each route as the router asks it (routers included by ``include_router`` are kept
    whole by FastAPI); mounts (the static files) aside: they take any method."""
    routes = [r for r in request.app.routes if not isinstance(r, Mount)]
    out = []
    for m in METHODS:
        scope = {**request.scope, "method": m}
        if any(r.matches(scope)[0] == Match.FULL for r in routes):
            out.append(m)
    return out


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
