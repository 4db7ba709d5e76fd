"""The lists of browser files each process serves (``server/service/web_files.py``) keep
up with ``web/``: every file a page or script refers to is listed for that page, every
page file in ``web/`` is on a list, and nothing of the npm tree is."""

from __future__ import annotations

import re

from server.service import web_files as wf

#: a page's references to files (``src=``, ``href=``) and a script's imports
REFS = re.compile(r"""(?:src|href)="([^"]+)"|import\s[^;]*?from\s+"([^"]+)"|import\("([^"]+)"\)""")


def refs(name: str) -> set[str]:
    """The local files ``web/<name>`` refers to, as paths from the site's root."""
    out = set()
    for m in REFS.finditer((wf.WEB_DIR / name).read_text(encoding="utf-8")):
        ref = next(g for g in m.groups() if g)
        if ref.startswith(("data:", "http:", "https:", "#")) or "${" in ref:
            continue
        out.add(ref.lstrip("./").removeprefix("../../").lstrip("/"))
    return out


def served(names: tuple[str, ...], index: str | None = None) -> set[str]:
    """What a process with these pages serves, as paths from the site's root."""
    files = set(wf.LOGIN) | set(names) | ({index} if index else set())
    return files | {f"vendor/uplot/{n}" for n in wf.UPLOT} | {"login", ""}


#: the routes (not files) a page links to
ROUTES = {"dashboard": {"residual", "viser/"}}


def test_every_reference_of_a_page_is_served_with_it() -> None:
    pages = {
        "dashboard": (wf.DASHBOARD, None),
        "fleet": (wf.FLEET, wf.FLEET_PAGE),
        "machine": (wf.MACHINE, wf.MACHINE_PAGE),
        "login": ((), None),
    }
    for page, (names, index) in pages.items():
        files = [*wf.LOGIN, *names, *([index] if index else [])]
        have = served(names, index) | ROUTES.get(page, set())
        for f in files:
            if f.endswith((".html", ".js")):
                missing = refs(f) - have
                assert not missing, f"{page}: {f} refers to {missing}, not served with it"


def test_every_page_file_is_on_a_list_and_no_npm_file_is() -> None:
    listed = {*wf.LOGIN, *wf.DASHBOARD, *wf.FLEET, *wf.MACHINE, wf.FLEET_PAGE, wf.MACHINE_PAGE}
    on_disk = {p.name for p in wf.WEB_DIR.iterdir() if p.suffix in (".html", ".js", ".css")}
    assert on_disk == listed, (on_disk - listed, listed - on_disk)
    assert not {n for n in listed if "node_modules" in n or n.startswith("package")}
    assert all((wf.UPLOT_DIR / n).is_file() for n in wf.UPLOT) or not wf.UPLOT_DIR.exists()


def test_a_reference_check_that_could_fail() -> None:
    page = wf.WEB_DIR / "index.html"
    assert {"app.js", "loop.js", "style.css", "vendor/uplot/uPlot.iife.min.js"} <= refs(page.name)
    assert "protocol.js" in refs("app.js") and "schema.js" in refs("protocol.js")
    assert refs("app.js") - served(("app.js",)), "app.js alone would miss its imports"
