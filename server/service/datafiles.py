"""Files of the service's data areas named in requests: logs (recordings, uploads) and
residual reports, found by plain name only (:class:`server.records.data_areas.DataStore`).

A request that names a path instead is refused with one answer whatever the path is
(:func:`refuse_path`), and a name that does not resolve gets the store's one answer
(:class:`~server.records.data_areas.NotFound`): the service is no oracle over the host's file
system. Messages of the log checks name the file by its name in its area, not by its
place on the server's disk.
"""

from __future__ import annotations

from pathlib import Path

from server.records.data_areas import DataStore, NotFound
from server.service.http_errors import FieldError

LOG_AREAS = ("recordings", "uploads")
LOG_SUFFIXES = (".csv", ".mat")

PATH_MSG = (
    "paths are not accepted: give the 'name' of a file in the service's data areas "
    "(recordings and uploads: GET /api/records, GET /api/uploads; reports: GET /residual)"
)


def refuse_path(got: str, instead: str = "name") -> FieldError:
    """The 422 for a request naming a path (the same message for every path)."""
    return FieldError("path", f"no path: use '{instead}'", got[:200], PATH_MSG)


def find_log(st: DataStore, name: str, area: str | None = None) -> tuple[str, Path]:
    """The log ``name`` (``.csv``/``.mat``, suffix optional) in ``area`` or, when None,
    in the recordings or the uploads.

    Raises
    ------
    FieldError
        ``name`` is in neither area (the store's one answer), or in both (``area``).
    """
    areas = (area,) if area is not None else LOG_AREAS
    found: list[tuple[str, Path]] = []
    for a in areas:
        try:
            p = st.resolve(a, name, suffixes=LOG_SUFFIXES)
        except NotFound:
            continue
        if p.is_file() and p.suffix.lower() in LOG_SUFFIXES:
            found.append((a, p))
    if not found:
        where = " or ".join(areas)
        exc = NotFound(where, name)
        raise FieldError("name", f"the name of a log in the service's {where}", name, str(exc))
    if len(found) > 1:
        raise FieldError(
            "area",
            f"one of {', '.join(LOG_AREAS)}",
            None,
            f"{name!r} is both a recording and an upload: say which with 'area'",
        )
    return found[0]


def find_report(st: DataStore, name: str) -> Path:
    """``report.json`` of the residual report ``name`` in the reports area.

    Raises
    ------
    FieldError
        No report of that name (the store's one answer).
    """
    try:
        d = st.resolve("reports", name)
        f = (d / "report.json").resolve()
        if not f.is_file() or st.area("reports").resolve() not in f.parents:
            raise NotFound("reports", name)  # missing, or a link out of the area
    except NotFound as exc:
        raise FieldError("report", "the name of a residual report (GET /residual)", name,
                         str(exc)) from None  # fmt: skip
    return f


def scrub(msg: str, path: Path, name: str) -> str:
    """``msg`` with the server-side path of ``path`` replaced by ``name``."""
    return msg.replace(str(path), name).replace(str(path.resolve()), name)
