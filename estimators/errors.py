"""Named exceptions raised by the estimators at their boundaries.

:class:`ParameterError` and the ``require_*`` checks are :mod:`common.errors`' (one class
for every layer); :class:`EstimatorError` is the base of this package's other errors.
"""

from __future__ import annotations

from common.errors import ParameterError, require_in, require_nonnegative, require_positive


class EstimatorError(Exception):
    """Base class of the other errors raised by :mod:`estimators`."""


__all__ = [
    "EstimatorError",
    "ParameterError",
    "require_in",
    "require_nonnegative",
    "require_positive",
]
