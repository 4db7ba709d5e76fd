"""Polling until a condition holds, for tests that wait on a server, a thread or a page."""

from __future__ import annotations

import time
from collections.abc import Callable
from typing import Any


def poll(pred: Callable[[], Any], timeout: float, period: float = 0.1) -> Any:
    """Call ``pred`` every ``period`` s until it returns something true, and return that;
    AssertionError when ``timeout`` s pass first."""
    deadline = time.monotonic() + timeout
    while True:
        v = pred()
        if v:
            return v
        if time.monotonic() > deadline:
            raise AssertionError("condition not reached in time")
        time.sleep(period)
