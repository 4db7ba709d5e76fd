"""Small statistics every layer uses."""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import ArrayLike


def rms(x: ArrayLike) -> float:
    """Root mean square (NaN for an empty array)."""
    a = np.asarray(x, dtype=np.float64)
    return float(np.sqrt(np.mean(a * a))) if a.size else math.nan
