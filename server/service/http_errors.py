"""The one error body of every 4xx: ``{"detail": [{"field", "allowed", "got", "msg"}]}``.

:func:`error` builds one entry; :class:`FieldError` is the service's named error for
bad request input (the app maps it to a 422 with that entry). The app's exception
handlers (``server.service.app``) turn every other 4xx (FastAPI's validation errors,
``ParameterError``, ``CutwatchError``, Starlette's 404/405, the token's 401, the body
limit's 413) into the same shape.
"""

from __future__ import annotations

import math
from typing import Any

from server.errors import CutwatchError


def _json_safe(v: Any) -> Any:
    """``v`` if it is a JSON scalar, else its repr (at most 80 characters).

    Used for the ``got`` of an error: a non-finite float comes back as ``"nan"`` or
    ``"inf"``, not ``null``, so that a client that sent NaN is not told it sent nothing
    (deliberate, unlike :func:`common.jsonsafe.json_safe`, used for the stream, where NaN
    means "no value yet"). A numpy
    scalar is its number (it came back as ``"np.float64(...)"`` before).
    """
    if getattr(v, "ndim", None) == 0 and hasattr(v, "item"):  # a numpy scalar: its number
        v = v.item()
    if isinstance(v, bool | int | str) or v is None:
        return v
    if isinstance(v, float) and math.isfinite(v):
        return v
    return repr(v)[:80]


def _sanitise(x: Any) -> Any:
    """Non-finite floats anywhere in ``x`` become their repr (JSON has no NaN)."""
    if isinstance(x, float) and not math.isfinite(x):
        return repr(x)
    if isinstance(x, dict):
        return {k: _sanitise(v) for k, v in x.items()}
    if isinstance(x, list | tuple):
        return [_sanitise(v) for v in x]
    return x


def error(field: str, allowed: str, got: Any, msg: str) -> dict[str, Any]:
    """One entry of an error body: the field, what it allows, what was found, a sentence."""
    return {"field": field, "allowed": allowed, "got": _json_safe(got), "msg": msg}


class FieldError(CutwatchError):
    """Bad request input: answered as a 422 naming the field, the allowed and the found."""

    def __init__(self, field: str, allowed: str, got: Any, msg: str) -> None:
        self.field, self.allowed, self.got = field, allowed, got
        super().__init__(msg)

    def entry(self) -> dict[str, Any]:
        return error(self.field, self.allowed, self.got, str(self))
