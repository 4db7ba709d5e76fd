"""Headless Chromium for the dashboard tests: Debian's browser, driven by Playwright.

``chromium_page`` opens one page and collects the page's script errors; the marks skip a
module when /usr/bin/chromium is not installed.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import pytest
from _wait import poll

CHROMIUM = Path("/usr/bin/chromium")
ARGS = (
    "--headless",
    "--no-sandbox",
    "--disable-gpu",
    "--disable-background-networking",
    "--disable-component-update",
)
#: ``pytestmark`` of a browser test module
MARKS = [
    pytest.mark.browser,
    pytest.mark.skipif(not CHROMIUM.exists(), reason="/usr/bin/chromium is not installed"),
]


def wait_for(pred: Callable[[], object], timeout: float = 15.0) -> Any:
    """Poll ``pred`` every 0.1 s until it is true; AssertionError after ``timeout`` s."""
    return poll(pred, timeout, 0.1)


@contextmanager
def chromium_page(
    width: int = 1280, height: int = 720, args: Sequence[str] = ARGS
) -> Iterator[tuple[Any, list[str]]]:
    """A page of a fresh headless Chromium and the list its script errors go into."""
    sync_api = pytest.importorskip("playwright.sync_api")
    with sync_api.sync_playwright() as p:
        browser = p.chromium.launch(executable_path=str(CHROMIUM), args=list(args))
        try:
            page = browser.new_page(viewport={"width": width, "height": height})
            errors: list[str] = []
            page.on("pageerror", lambda e: errors.append(str(e)))
            yield page, errors
        finally:
            browser.close()


def log_in(page: Any, base: str, token: str | None) -> None:
    """Open the dashboard at ``base``; with a token set, through the login page (the
    service answers a page without a session with a redirect to /login)."""
    page.goto(f"{base}/")
    if token is None:
        return
    page.wait_for_url("**/login", timeout=15000)
    page.fill("#token", token)
    page.click("#submit")
    page.wait_for_url(f"{base}/", timeout=15000)
