"""The application: pipeline wiring, reproductions, benchmarks, command line, live service.

Composes :mod:`machine` and :mod:`estimators`; nothing imports it. Sub-modules are
imported where used (the command line must start fast), so this package re-exports only
the reproduction contract.
"""

from server.reproduce import Check, Reproduction, Row

__all__ = ["Check", "Reproduction", "Row"]
