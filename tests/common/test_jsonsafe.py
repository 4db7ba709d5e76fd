"""json_safe: non-finite floats become null, numpy becomes Python, never a repr."""

from __future__ import annotations

import json
import math

import numpy as np

from common.jsonsafe import json_safe


def test_non_finite_floats_become_none_everywhere() -> None:
    x = {"a": math.nan, "b": [math.inf, -math.inf, 1.5], "c": (np.float64("nan"), 2)}
    assert json_safe(x) == {"a": None, "b": [None, None, 1.5], "c": [None, 2]}


def test_numpy_scalars_and_arrays_become_python() -> None:
    out = json_safe({1: np.float32(0.5), "i": np.int64(3), "ok": np.bool_(True)})
    assert out == {"1": 0.5, "i": 3, "ok": True}
    assert type(out["i"]) is int and type(out["ok"]) is bool
    arr = json_safe(np.array([[1.0, np.nan], [np.inf, 4.0]]))
    assert arr == [[1.0, None], [None, 4.0]]
    assert type(json_safe(np.float64(2.0))) is float


def test_the_result_dumps_as_strict_json() -> None:
    x = {"rows": [np.float64(-np.inf), np.arange(3)], "s": "text", "n": None}
    text = json.dumps(json_safe(x), allow_nan=False)
    assert json.loads(text) == {"rows": [None, [0, 1, 2]], "s": "text", "n": None}
