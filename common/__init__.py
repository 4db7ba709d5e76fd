"""Definitions every layer may import: the parameter error, array types, shared constants.

Imports nothing of ours (checked by the import contract in ``pyproject.toml``), so
:mod:`machine` and :mod:`estimators` can share it and stay independent of each other.
"""

from common.arrays import F64
from common.errors import ParameterError, require_in, require_nonnegative, require_positive

__all__ = ["F64", "ParameterError", "require_in", "require_nonnegative", "require_positive"]
