"""The parameter error raised at every boundary of machine, estimators and server.

One class, so the service maps it to a field-level 422 with one handler.
"""

from __future__ import annotations

import math
from typing import Any


class ParameterError(ValueError):
    """A parameter is outside its allowed range.

    The message names the parameter, the allowed range and the value given.
    """

    def __init__(self, name: str, expected: str, got: Any) -> None:
        self.name = name
        self.expected = expected
        self.got = got
        super().__init__(f"parameter {name!r}: expected {expected}, got {got!r}")


def require_positive(name: str, value: float) -> float:
    """Return ``value`` as float if it is finite and > 0, else raise :class:`ParameterError`."""
    v = float(value)
    if not math.isfinite(v) or v <= 0.0:
        raise ParameterError(name, "a finite value > 0", value)
    return v


def require_nonnegative(name: str, value: float) -> float:
    """Return ``value`` as float if it is finite and >= 0, else raise :class:`ParameterError`."""
    v = float(value)
    if not math.isfinite(v) or v < 0.0:
        raise ParameterError(name, "a finite value >= 0", value)
    return v


def require_in(
    name: str, value: float, lo: float, hi: float, *, lo_open: bool = False, hi_open: bool = False
) -> float:
    """Return ``value`` if it lies in the interval given, else raise :class:`ParameterError`."""
    v = float(value)
    ok = math.isfinite(v)
    ok = ok and (v > lo if lo_open else v >= lo) and (v < hi if hi_open else v <= hi)
    if not ok:
        left = "(" if lo_open else "["
        right = ")" if hi_open else "]"
        raise ParameterError(name, f"a value in {left}{lo:g}, {hi:g}{right}", value)
    return v
