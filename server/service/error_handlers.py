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
from typing import Any, get_args

from fastapi import FastAPI, Request
from fastapi.exceptions import RequestValidationError
from fastapi.responses import JSONResponse, Response
from pydantic import BaseModel
from starlette.exceptions import HTTPException as StarletteHTTPException
from starlette.routing import Match, Mount

from common.errors import ParameterError
from server.errors import CutwatchError
from server.service.http_errors import (
    ErrorEntry,
    FieldError,
    SafeJSONResponse,
    echo,
    error,
    sanitise,
)


def install(app: FastAPI) -> None:
    """Register the handlers on ``app``."""
    app.exception_handler(RequestValidationError)(_validation_error)
    app.exception_handler(ParameterError)(_parameter_error)
    app.exception_handler(CutwatchError)(_cutwatch_error)
    app.exception_handler(StarletteHTTPException)(_http_error)


def _errors(status: int, items: Sequence[ErrorEntry], **kw: Any) -> JSONResponse:
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


def _validation_item(request: Request, e: Any) -> ErrorEntry:
    tagged = _tagged_union(request)
    if tagged is not None:
        e = _untagged(e, *tagged)
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
    if kind in ("literal_error", "enum"):
        allowed = f"one of {ctx.get('expected', '')}"
    elif kind == "extra_forbidden":
        names = ctx.get("fields") or _body_fields(request)
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


def _tagged_union(request: Request) -> tuple[str, dict[str, type[BaseModel]]] | None:
    """The route's body when it is a union of models told apart by one field (``Control``
    by its ``action``): that field, and each of its values' model."""
    route = request.scope.get("route")
    info = getattr(getattr(route, "body_field", None), "field_info", None)
    tag = getattr(info, "discriminator", None)
    if not isinstance(tag, str):
        return None
    models: dict[str, type[BaseModel]] = {}
    for model in get_args(getattr(info, "annotation", None)):
        field = getattr(model, "model_fields", {}).get(tag)
        if field is not None:
            models.update({str(v): model for v in get_args(field.annotation)})
    return tag, models


def _or_list(tags: str) -> str:
    """``'a', 'b', 'c'`` as pydantic lists the values a literal allows: ``'a', 'b' or 'c'``."""
    head, sep, last = tags.rpartition(", ")
    return f"{head} or {last}" if sep else tags


def _untagged(e: Any, tag: str, models: dict[str, type[BaseModel]]) -> Any:
    """A tagged union's error as the same error of one flat model: the tag field refused
    as a literal, the tag left out of a field's location, a field of the action missing
    or belonging to another action said in those words."""
    loc, kind, ctx = tuple(e.get("loc") or ()), e.get("type"), e.get("ctx") or {}
    if kind == "union_tag_invalid":
        allowed = _or_list(str(ctx.get("expected_tags", "")))
        msg = f"Input should be {allowed}"
        body = e.get("input")
        got = body.get(tag) if isinstance(body, dict) else ctx.get("tag")
        return {"type": "literal_error", "loc": (*loc, tag), "msg": msg, "input": got,
                "ctx": {"expected": allowed}}  # fmt: skip
    if kind == "union_tag_not_found":
        return {"type": "missing", "loc": (*loc, tag), "msg": "Field required", "input": None}
    if len(loc) < 2 or loc[1] not in models:
        return e
    action, name = str(loc[1]), loc[-1]
    loc = (loc[0], *loc[2:])
    if kind == "missing":
        allowed = f"a value (required with action '{action}')"
        return {"type": "missing_for_action", "loc": loc, "msg": allowed,
                "ctx": {"field": name, "got": None}}  # fmt: skip
    if kind == "extra_forbidden":
        owner = next((t for t, m in models.items() if name in m.model_fields), None)
        if owner is not None:
            allowed = f"no {name} (it belongs to action '{owner}')"
            return {"type": "refused", "loc": loc, "msg": allowed,
                    "ctx": {"field": name, "got": e.get("input")}}  # fmt: skip
        return {**e, "loc": loc, "ctx": {**ctx, "fields": list(models[action].model_fields)}}
    return {**e, "loc": loc}


def _body_fields(request: Request) -> list[str]:
    """Field names of the route's request body model (for 'extra field' errors)."""
    route = request.scope.get("route")
    body = getattr(route, "body_field", None)
    model = getattr(getattr(body, "field_info", None), "annotation", None)
    fields = getattr(model, "model_fields", None)
    return list(fields) if isinstance(fields, dict) else []
