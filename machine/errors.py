"""Named exceptions raised by the machine simulation at their boundaries.

:class:`ParameterError` and the ``require_*`` checks are :mod:`common.errors`' (one class
for every layer); :class:`MachineError` is the base of this package's other errors.
"""

from __future__ import annotations

from common.errors import ParameterError, require_in, require_nonnegative, require_positive


class MachineError(Exception):
    """Base class of the other errors raised by :mod:`machine`."""


__all__ = [
    "MachineError",
    "ParameterError",
    "require_in",
    "require_nonnegative",
    "require_positive",
]
