"""Test-wide settings and the marks that split the fast loop from the full suite.

Under CI (``CI=true``) hypothesis runs derandomised: the same examples every run, so a
submission's result does not depend on which random examples a run happened to draw.
Locally it explores with fresh examples (and keeps failures in its database).

``make test-fast`` runs the unit and property tests: ``-m "not slow and not server and not
broker and not browser and not image"``. A test is marked here by what it starts, read from
the helpers its module imports, so a new test that starts one is marked without anyone
remembering to:

- ``server``: a real uvicorn server (``tests/_live.py``);
- ``broker``: a real Mosquitto (``tests/_broker.py``);
- ``browser``: headless Chromium (``tests/_browser.py``, marked by its ``MARKS``);
- ``slow``: a long reproduction, Monte Carlo, data set or CLI run (over ~5 s each,
  measured): marked by hand, and every test under ``tests/experiments/`` and
  ``tests/cli/`` (each runs a reproduction or a whole command: 23 min for tests/cli on
  this machine under load).

The README's "The fast test loop" has the table; ``docs/architecture.md#tests`` the
times measured.
"""

from __future__ import annotations

import os
import types

import pytest
from hypothesis import settings

settings.register_profile("ci", derandomize=True, print_blob=True)
if os.environ.get("CI", "").lower() in ("1", "true", "yes"):
    settings.load_profile("ci")

#: helper module of tests/ -> the mark of every test in a module that imports from it
HELPER_MARKS = {"_live": "server", "_broker": "broker", "_browser": "browser", "_opcua": "server"}
#: test folders whose every test is slow: each runs a reproduction, or a whole command
#: (a residual analysis, a simulation, a benchmark) in a real sub-process or through main()
SLOW_DIRS = ("experiments", "cli")
TESTS = os.path.dirname(os.path.abspath(__file__))


def _helpers(module: types.ModuleType) -> set[str]:
    """The test helpers (``tests/_*.py``) a test module imports from."""
    found = set()
    for value in vars(module).values():
        name = value.__name__ if isinstance(value, types.ModuleType) else None
        name = name or getattr(value, "__module__", None)
        if name in HELPER_MARKS:
            found.add(name)
    return found


def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    """Mark every test by the real parts its module starts (see the module docstring)."""
    seen: dict[str, set[str]] = {}
    for item in items:
        module = getattr(item, "module", None)
        if module is None:
            continue
        helpers = seen.setdefault(module.__name__, _helpers(module))
        for helper in sorted(helpers):
            item.add_marker(HELPER_MARKS[helper])
        folder = os.path.relpath(str(item.path), TESTS).split(os.sep)[0]
        if folder in SLOW_DIRS:
            item.add_marker("slow")
