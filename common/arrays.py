"""Array types."""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

#: A float64 array of any shape: every signal, state and parameter vector.
F64 = NDArray[np.float64]
