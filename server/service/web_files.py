"""The browser files each process serves: its pages' own, listed, and nothing else.

``web/`` also holds the npm tree of the dashboard's one third-party package
(``package.json``, ``package-lock.json``, ``node_modules/``): none of it is served but
the two uPlot files the dashboard loads (:data:`UPLOT`, at ``/vendor/uplot/``). Each
process lists its pages' files (:data:`DASHBOARD`, :data:`FLEET`, :data:`MACHINE`) and
every one serves the login page's (:data:`LOGIN`); a name not listed is a 404 in the
service's error body, whatever is on disk (``web/`` itself is not listed: no directory
listing anywhere). ``tests/service/test_web_files.py`` checks
that every file a listed page or script refers to is listed, and that every page file in
``web/`` belongs to a list.
"""

from __future__ import annotations

from collections.abc import Iterable
from pathlib import Path

from starlette.exceptions import HTTPException
from starlette.responses import Response
from starlette.staticfiles import StaticFiles
from starlette.types import Scope

WEB_DIR = Path(__file__).resolve().parents[2] / "web"
UPLOT_DIR = WEB_DIR / "node_modules" / "uplot" / "dist"

#: the login page's files (served by every process: ``/login`` is a route)
LOGIN = ("login.html", "login.js", "style.css")
#: the live dashboard of ``cutwatch serve`` (``/`` is its index.html)
DASHBOARD = (
    "index.html", "app.js", "charts.js", "loop.js", "panels.js", "monitor.js",
    "protocol.js", "schema.js", "style.css",
)  # fmt: skip
#: the fleet page of ``cutwatch fleet``: its script (the page, fleet.html, is ``/``)
FLEET = ("fleet.js",)
FLEET_PAGE = "fleet.html"
#: a machine's page of ``cutwatch worker``: its script (the page, machine.html, is the
#: route ``/m/<machine>/``, which checks the machine)
MACHINE = ("machine.js",)
MACHINE_PAGE = "machine.html"
#: what the dashboard loads of uPlot's distribution (``/vendor/uplot/``)
UPLOT = ("uPlot.iife.min.js", "uPlot.min.css")


class ListedFiles(StaticFiles):
    """Starlette's static files, answering only the names listed, and ``index`` at the
    mount's own path (``/``); any other name is a 404, even when it exists."""

    def __init__(self, directory: Path, names: Iterable[str], index: str | None = None) -> None:
        super().__init__(directory=directory)
        self.names = frozenset(names)
        self.index = index

    async def get_response(self, path: str, scope: Scope) -> Response:
        if path == "." and self.index:
            return await super().get_response(self.index, scope)
        if scope["method"] in ("GET", "HEAD") and path not in self.names:
            raise HTTPException(status_code=404)
        return await super().get_response(path, scope)


def page_files(*pages: Iterable[str], index: str | None = None) -> ListedFiles:
    """The files of these pages and the login page's, from ``web/`` (mount at ``/``)."""
    names = {n for page in (LOGIN, *pages) for n in page}
    return ListedFiles(WEB_DIR, names, index=index)


def uplot_files() -> ListedFiles | None:
    """uPlot's two files (mount at ``/vendor/uplot``); None when npm has not run."""
    return ListedFiles(UPLOT_DIR, UPLOT) if UPLOT_DIR.is_dir() else None
