"""Residual reports on disk: ``/residual`` (index), ``/residual/{name}/`` and its report.json."""

from __future__ import annotations

import html
from pathlib import Path

from fastapi import APIRouter, HTTPException
from fastapi.responses import FileResponse, HTMLResponse

from server.records.data_areas import check_name
from server.service.deps import Config
from server.service.http_errors import error
from server.service.schemas import ResidualReport, error_responses

router = APIRouter(prefix="/residual", tags=["reports"], responses=error_responses())

_NAME_RULE = "a directory name: letters, digits, '.', '_', '-', not starting with '.'"


def residual_reports(root: Path) -> list[str]:
    """Sub-directories of ``root`` holding a report.html, sorted."""
    if not root.is_dir():
        return []
    return sorted(
        d.name for d in root.iterdir() if check_name(d.name) and (d / "report.html").is_file()
    )


def report_file(root: Path, name: str, leaf: str) -> Path:
    """``root/name/leaf``, refusing any name that would leave ``root``.

    Raises
    ------
    HTTPException
        404 for an unknown or unsafe name (path traversal) or a missing file.
    """
    base = root.resolve()
    if not check_name(name):
        msg = f"no residual report named {name!r} (expected a directory name)"
        raise HTTPException(404, detail=[error("name", _NAME_RULE, name, msg)])
    f = (base / name / leaf).resolve()
    if not f.is_relative_to(base) or not f.is_file():
        msg = f"no residual report named {name!r} in the reports area (GET /residual)"
        raise HTTPException(404, detail=[error("name", "a report listed at /residual", name, msg)])
    return f


@router.get(
    "",
    response_class=HTMLResponse,
    summary="residual reports on disk",
    responses=error_responses(json_route=False),
)
def residual_index(s: Config) -> HTMLResponse:
    rows = "".join(
        f'<li><a href="/residual/{html.escape(n)}/">{html.escape(n)}</a></li>'
        for n in residual_reports(s.reports_area)
    )
    body = rows or "<li>none yet: <code>cutwatch residual LOG --out DIR</code></li>"
    return HTMLResponse(
        "<!doctype html><html><head><meta charset='utf-8'><title>cutwatch residual "
        "reports</title></head><body><h1>Residual reports</h1>"
        f"<ul>{body}</ul></body></html>"
    )


@router.get(
    "/{name}/",
    response_class=HTMLResponse,
    summary="one residual report (its report.html)",
    responses=error_responses(404, json_route=False),
)
def residual_report(name: str, s: Config) -> FileResponse:
    return FileResponse(report_file(s.reports_area, name, "report.html"))


@router.get(
    "/{name}/report.json",
    summary="one residual report (its report.json)",
    response_model=None,
    responses={200: {"model": ResidualReport}, **error_responses(404)},
)
def residual_report_json(name: str, s: Config) -> FileResponse:
    return FileResponse(report_file(s.reports_area, name, "report.json"))
