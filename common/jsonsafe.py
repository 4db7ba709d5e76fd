"""JSON-safe copies of results: JSON has no NaN or infinity and knows no numpy types."""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

import numpy as np


def json_safe(x: Any) -> Any:
    """A copy of ``x`` that ``json.dumps`` accepts and that keeps its numbers.

    Non-finite floats become ``None`` (never their repr); numpy scalars become Python
    scalars and numpy arrays nested lists; mappings become dicts with string keys;
    tuples become lists. Anything else is returned as it is.
    """
    if x is None or isinstance(x, bool | int | str):
        return x
    if isinstance(x, np.ndarray):
        return json_safe(x.tolist())
    if isinstance(x, np.generic):
        return json_safe(x.item())
    if isinstance(x, float):
        return float(x) if math.isfinite(x) else None
    if isinstance(x, Mapping):
        return {str(k): json_safe(v) for k, v in x.items()}
    if isinstance(x, list | tuple):
        return [json_safe(v) for v in x]
    return x
