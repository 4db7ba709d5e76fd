"""Errors of the application layer, and which exceptions are the user's to fix."""

from __future__ import annotations

from common.errors import ParameterError
from estimators.errors import EstimatorError
from machine.errors import MachineError


class CutwatchError(Exception):
    """Base class of the application layer's named errors (bad input, files, options)."""


class LogFormatError(CutwatchError, ValueError):
    """A measured log (file, column, row) does not match the log format (docs/design.md)."""


def is_user_error(exc: BaseException) -> bool:
    """True for named errors that describe bad input (printed without a traceback)."""
    return isinstance(exc, CutwatchError | EstimatorError | MachineError | ParameterError)
