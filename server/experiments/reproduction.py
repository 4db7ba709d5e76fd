"""The reproduction contract: rows (ours beside the paper's) and checks.

Each module in :mod:`server.experiments.reproductions` defines ``NAME`` (the experiment name used
on the command line), ``SOURCE`` (seed file and table) and
``run(*, quick: bool, plot_dir: Path | None, progress: bool) -> Reproduction``.
``quick`` runs a reduced length at which the checks still hold (used by the tests).
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, field
from types import ModuleType
from typing import TypedDict

from common.jsonsafe import json_safe
from server.plugins import plugin_modules


class RowJson(TypedDict):
    """A row of ``cutwatch reproduce --json``: ours beside the paper's, with the condition."""

    name: str
    ours: float | None
    paper: float | None
    unit: str
    condition: str


class CheckJson(TypedDict):
    """A check of ``cutwatch reproduce --json``: whether it holds, its value and limit."""

    name: str
    holds: bool
    value: float | None
    limit: float | None


class ReproductionJson(TypedDict):
    """``cutwatch reproduce NAME --json`` (:meth:`Reproduction.to_json`)."""

    experiment: str
    source: str
    rows: list[RowJson]
    checks: list[CheckJson]
    figures: list[str]


@dataclass(frozen=True)
class Row:
    """One reproduced number beside the paper's."""

    name: str
    ours: float
    paper: float | None
    unit: str
    condition: str = ""


@dataclass(frozen=True)
class Check:
    """A property that must hold on our run."""

    name: str
    holds: bool
    value: float
    limit: float


#: one section of a reproduction: its rows and its checks, each in order
Section = tuple[list[Row], list[Check]]


@dataclass
class Reproduction:
    """Result of one reproduction run."""

    experiment: str
    source: str
    rows: list[Row] = field(default_factory=list)
    checks: list[Check] = field(default_factory=list)
    figures: list[str] = field(default_factory=list)

    def add(self, section: Section) -> None:
        """Append a section's rows and checks."""
        rows, checks = section
        self.rows.extend(rows)
        self.checks.extend(checks)

    def row(self, name: str) -> Row:
        for r in self.rows:
            if r.name == name:
                return r
        raise KeyError(name)

    def to_json(self) -> ReproductionJson:
        def clean(x: float | None) -> float | None:
            return None if x is None else json_safe(float(x))

        return {
            "experiment": self.experiment,
            "source": self.source,
            "rows": [
                {
                    "name": r.name,
                    "ours": clean(r.ours),
                    "paper": clean(r.paper),
                    "unit": r.unit,
                    "condition": r.condition,
                }
                for r in self.rows
            ],
            "checks": [
                {
                    "name": c.name,
                    "holds": bool(c.holds),
                    "value": clean(c.value),
                    "limit": clean(c.limit),
                }
                for c in self.checks
            ],
            "figures": list(self.figures),
        }

    @property
    def all_hold(self) -> bool:
        return all(c.holds for c in self.checks)


def _fmt(x: float | None) -> str:
    if x is None:
        return "-"
    if not math.isfinite(x):
        return str(x)
    a = abs(x)
    if a != 0 and (a >= 1e5 or a < 1e-3):
        return f"{x:.4g}"
    return f"{x:.4f}".rstrip("0").rstrip(".") if a < 100 else f"{x:.2f}"


def format_table(rep: Reproduction) -> str:
    """The human table: name, ours, paper, unit, condition; then the checks."""
    head = ("row", "ours", "paper", "unit", "condition")
    body = [(r.name, _fmt(r.ours), _fmt(r.paper), r.unit, r.condition) for r in rep.rows]
    widths = [
        max(len(h), *(len(b[i]) for b in body)) if body else len(h) for i, h in enumerate(head)
    ]
    lines = [f"# {rep.experiment} — {rep.source}"]
    lines.append("  ".join(h.ljust(w) for h, w in zip(head, widths, strict=True)).rstrip())
    lines.append("  ".join("-" * w for w in widths))
    for b in body:
        lines.append("  ".join(c.ljust(w) for c, w in zip(b, widths, strict=True)).rstrip())
    if rep.checks:
        lines.append("")
        lines.append("checks:")
        for c in rep.checks:
            mark = "PASS" if c.holds else "FAIL"
            lines.append(f"  [{mark}] {c.name}: value {_fmt(c.value)} (limit {_fmt(c.limit)})")
    if rep.figures:
        lines.append("")
        lines.append("figures: " + ", ".join(rep.figures))
    return "\n".join(lines)


def discover() -> dict[str, ModuleType]:
    """Map experiment name -> module, for every module in the reproductions package."""
    from server.experiments import reproductions

    found: dict[str, ModuleType] = {}
    for mod in plugin_modules(reproductions):
        name = getattr(mod, "NAME", None)
        if isinstance(name, str):
            found[name] = mod
    return found


def dumps(rep: Reproduction) -> str:
    return json.dumps(rep.to_json(), indent=2)


__all__ = ["Check", "Reproduction", "Row", "Section", "discover", "dumps", "format_table"]
