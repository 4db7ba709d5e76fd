"""The service's own data directories, and files in them by name only.

Replay, analysis, effect installs and downloads read files only from here: recordings
(``cutwatch record`` / ``POST /api/record``), uploads (logs sent to the service) and
reports (``cutwatch residual --out``). A client names a file; it never gives a path. A
name is one path component of letters, digits and ``_ . -`` (no ``/``, no leading dot,
no ``..``); the resolved file must lie inside its directory after following symbolic
links, so a link pointing out is refused like a traversal. Refusals say only that no
such item exists in that area: the service is no oracle over the host's file system.
"""

from __future__ import annotations

import builtins
import re
import shutil
import tempfile
from dataclasses import dataclass
from pathlib import Path

from server.errors import CutwatchError

AREAS = ("recordings", "uploads", "reports")
#: where uploads wait for their check (under the root; never an area)
QUARANTINE = ".quarantine"
#: a plain name, matched whole (``fullmatch``: ``$`` would let a final newline through)
_NAME_RE = re.compile(r"[A-Za-z0-9][A-Za-z0-9_.-]{0,127}")


class NotFound(CutwatchError, LookupError):
    """No item of that name in that area (or the name is not a plain name)."""

    def __init__(self, area: str, name: str) -> None:
        self.area = area
        self.name = name
        super().__init__(
            f"{area}: no item named {name!r} (expected the name of one of the service's "
            f"{area}, as listed by the API; paths are not accepted)"
        )


def check_name(name: str) -> bool:
    """True for a plain item name (one component, no traversal)."""
    return isinstance(name, str) and bool(_NAME_RE.fullmatch(name)) and ".." not in name


@dataclass(frozen=True)
class DataStore:
    """The root holding ``recordings/``, ``uploads/`` and ``reports/`` (made on demand;
    ``reports`` may point the reports area elsewhere)."""

    root: Path
    #: the reports area when it lies elsewhere (the service's ``reports_dir``)
    reports: Path | None = None

    def area(self, area: str) -> Path:
        if area not in AREAS:
            raise ValueError(f"area {area!r}: expected one of {AREAS}")
        d = self.reports if area == "reports" and self.reports is not None else self.root / area
        d.mkdir(parents=True, exist_ok=True)
        return d

    def resolve(self, area: str, name: str, *, suffixes: tuple[str, ...] = ()) -> Path:
        """The existing file or directory ``name`` in ``area``.

        ``suffixes`` (e.g. ``(".csv",)``) are tried when ``name`` has none of them.

        Raises
        ------
        NotFound
            The name is not plain, does not exist, or resolves outside the area.
        """
        if not check_name(name):
            raise NotFound(area, name)
        base = self.area(area).resolve()
        for cand in (name, *(name + s for s in suffixes if not name.endswith(s))):
            p = base / cand
            if not p.exists():
                continue
            real = p.resolve()
            if real == base or base not in real.parents:
                raise NotFound(area, name)
            return real
        raise NotFound(area, name)

    def new_path(self, area: str, name: str) -> Path:
        """Where a new item ``name`` goes (the name checked; the file need not exist)."""
        if not check_name(name):
            raise CutwatchError(
                f"name {name!r}: expected 1-128 characters from A-Z a-z 0-9 _ . - "
                "starting with a letter or digit"
            )
        return self.area(area) / name

    def list(self, area: str, pattern: str = "*") -> list[Path]:
        """Items in ``area`` matching ``pattern`` (no hidden or temporary files), sorted."""
        base = self.area(area)
        return sorted(
            p for p in base.glob(pattern) if check_name(p.name) and not p.name.endswith(".tmp")
        )

    def quarantine(self, prefix: str = "upload-") -> Path:
        """A fresh private directory under ``.quarantine/`` of the root, where a file
        waits for its check: no area lists it and no name resolves into it."""
        base = self.root / QUARANTINE
        base.mkdir(parents=True, exist_ok=True)
        return Path(tempfile.mkdtemp(prefix=prefix, dir=base))

    def clean_stale(self) -> builtins.list[str]:
        """Remove what an interrupted process left (call at start-up, before anything
        runs): the quarantine, temporary files of recordings and uploads
        (``.<name>.<random>.tmp``) and unfinished analysis directories (``.job-*``).
        Returns what was removed, as ``area/name``."""
        gone: builtins.list[str] = []
        q = self.root / QUARANTINE
        if q.is_dir():
            gone += [f"{QUARANTINE}/{p.name}" for p in sorted(q.iterdir())]
            shutil.rmtree(q, ignore_errors=True)
        for area, pattern in (("recordings", ".*.tmp"), ("uploads", ".*.tmp"),
                              ("reports", ".job-*")):  # fmt: skip
            d = self.area(area)
            for p in sorted(d.glob(pattern)):
                if p.is_dir() and not p.is_symlink():
                    shutil.rmtree(p, ignore_errors=True)
                else:
                    p.unlink(missing_ok=True)
                gone.append(f"{area}/{p.name}")
        return gone
