"""The one error body of every 4xx: ``{"detail": [{"field", "allowed", "got", "msg"}]}``.

:func:`error` builds one entry; :class:`FieldError` is the service's named error for
bad request input (the app maps it to a 422 with that entry). The app's exception
handlers (``server.service.app``) turn every other 4xx (FastAPI's validation errors,
``ParameterError``, ``CutwatchError``, Starlette's 404/405, the access checks' 401/403,
the body limit's 413) into the same shape, rendered by :class:`SafeJSONResponse` (an
echoed lone surrogate cannot turn a 422 into a 500).
"""

from __future__ import annotations

import json
import math
from typing import Any, TypedDict

from fastapi.responses import JSONResponse
from pydantic import JsonValue

from server.errors import CutwatchError

#: how deep and how wide an echoed input is kept (deeper: its repr, cut)
MAX_DEPTH = 4
MAX_ITEMS = 20
MAX_TEXT = 200


def _text(s: str, limit: int = MAX_TEXT) -> str:
    """``s`` cut to ``limit`` characters, lone surrogates written as ``\\udXXX``."""
    s = s[:limit]
    try:
        s.encode("utf-8")
    except UnicodeEncodeError:
        s = s.encode("utf-8", "backslashreplace").decode("utf-8")
    return s


def echo(v: Any) -> Any:
    """``v`` if it is a JSON scalar, else its repr (at most 80 characters).

    Used for the ``got`` of an error: a non-finite float comes back as ``"nan"`` or
    ``"inf"``, not ``null``, so that a client that sent NaN is not told it sent nothing
    (deliberate, unlike :func:`common.jsonsafe.json_safe`, used for the stream, where NaN
    means "no value yet"). A numpy scalar is its number; an integer too large for a
    double is described by its number of digits; text is cut and made encodable.
    """
    if getattr(v, "ndim", None) == 0 and hasattr(v, "item"):  # a numpy scalar: its number
        v = v.item()
    if isinstance(v, bool) or v is None:
        return v
    if isinstance(v, int):
        if abs(v) < 2**63:
            return v
        return f"an integer of about {int(v.bit_length() * math.log10(2)) + 1} digits"
    if isinstance(v, str):
        return _text(v)
    if isinstance(v, float):
        return v if math.isfinite(v) else repr(v)
    return _text(_repr(v), 80)


def _repr(v: Any) -> str:
    try:
        return repr(sanitise(v) if isinstance(v, dict | list | tuple) else v)
    except (RecursionError, ValueError):
        return f"a {type(v).__name__}"


def sanitise(x: Any, depth: int = 0) -> Any:
    """A JSON-safe echo of a request's input, bounded: non-finite floats as their repr,
    at most :data:`MAX_DEPTH` levels and :data:`MAX_ITEMS` items per level (a body nested
    500 deep is cut, not recursed into), strings cut and made encodable."""
    if isinstance(x, dict | list | tuple):
        if depth >= MAX_DEPTH:
            return f"(a {type(x).__name__} nested deeper than {MAX_DEPTH} levels)"
        if isinstance(x, dict):
            items = list(x.items())[:MAX_ITEMS]
            return {_text(str(k), 80): sanitise(v, depth + 1) for k, v in items}
        return [sanitise(v, depth + 1) for v in list(x)[:MAX_ITEMS]]
    if isinstance(x, float) and not math.isfinite(x):
        return repr(x)
    if isinstance(x, bool | int | float | str) or x is None:
        return echo(x)
    return _text(f"a {type(x).__name__}", 80)


class ErrorEntry(TypedDict):
    """One entry of the service's error body (``{"detail": [entry, ...]}``)."""

    field: str  # the refused field (a dotted path into the body, a header, a query)
    allowed: str  # what it allows
    got: JsonValue  # what was found (JSON-safe, bounded)
    msg: str  # one sentence


def error(field: str, allowed: str, got: Any, msg: str) -> ErrorEntry:
    """One entry of an error body: the field, what it allows, what was found, a sentence."""
    return {
        "field": _text(str(field)),
        "allowed": _text(str(allowed), 1000),
        "got": echo(got),
        "msg": _text(str(msg), 2000),
    }


class SafeJSONResponse(JSONResponse):
    """A JSON answer that never fails to encode: text that UTF-8 cannot carry (a lone
    surrogate echoed from a request) is written with ``\\u`` escapes."""

    def render(self, content: Any) -> bytes:
        try:
            return super().render(content)
        except UnicodeEncodeError:
            return json.dumps(content, ensure_ascii=True, allow_nan=False).encode("ascii")


class FieldError(CutwatchError):
    """Bad request input: answered as a 422 naming the field, the allowed and the found."""

    def __init__(self, field: str, allowed: str, got: Any, msg: str) -> None:
        self.field, self.allowed, self.got = field, allowed, got
        super().__init__(msg)

    def entry(self) -> ErrorEntry:
        return error(self.field, self.allowed, self.got, str(self))
