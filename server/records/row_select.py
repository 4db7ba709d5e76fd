"""Rows of a measured log chosen by conditions on its columns, text labels included.

A condition is ``TERM [& TERM ...]`` (all terms must hold), a term ``COLUMN OP VALUE``
with ``OP`` one of ``==``, ``!=``, ``<``, ``<=``, ``>``, ``>=`` (numbers, or text for
``==``/``!=``) or ``~`` (the cell matches the regular expression ``VALUE``, searched
anywhere in the cell; numbers are matched as written in the file). Examples::

    Machining_Process~^Layer
    S1_ActualVelocity<1 & X1_ActualPosition==198
    Machining_Process==Repositioning

Conditions are parsed by a regular expression, never evaluated as code. Every refusal
names the option, the column and, where a cell is at fault, the row, with what was
expected against what was found.
"""

from __future__ import annotations

import fnmatch
import re
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import TypedDict

import numpy as np
from numpy.typing import NDArray

from server.errors import LogFormatError

OPS: tuple[str, ...] = ("==", "!=", "<=", ">=", "<", ">", "~")
_TERM_RE = re.compile(
    r"^\s*(?P<col>[A-Za-z_][A-Za-z0-9_.]*)\s*(?P<op>==|!=|<=|>=|<|>|~)\s*(?P<val>.*?)\s*$"
)

Column = NDArray[np.float64] | NDArray[np.str_]


@dataclass(frozen=True)
class Term:
    """One ``COLUMN OP VALUE`` of a condition."""

    column: str
    op: str
    value: str


@dataclass(frozen=True)
class Condition:
    """A conjunction of terms, with the option text it came from (for messages)."""

    text: str
    terms: tuple[Term, ...]
    option: str = "--keep"

    def __str__(self) -> str:
        return f"{self.option} {self.text!r}"


def parse_condition(text: str, option: str = "--keep") -> Condition:
    """Parse ``TERM [& TERM ...]`` strictly.

    Raises
    ------
    LogFormatError
        If a term is not ``COLUMN OP VALUE`` or a regular expression does not compile.
    """
    terms: list[Term] = []
    for part in text.split("&"):
        m = _TERM_RE.match(part)
        if m is None or m.group("val") == "":
            raise LogFormatError(
                f"{option} {text!r}: term {part.strip()!r}: expected COLUMN OP VALUE with OP "
                f"one of {' '.join(OPS)} (e.g. Machining_Process~^Layer or S1_ActualVelocity<1)"
            )
        val = m.group("val")
        if len(val) >= 2 and val[0] == val[-1] and val[0] in "'\"":
            val = val[1:-1]
        if m.group("op") == "~":
            try:
                re.compile(val)
            except re.error as exc:
                raise LogFormatError(
                    f"{option} {text!r}: {val!r}: expected a regular expression ({exc})"
                ) from None
        terms.append(Term(m.group("col"), m.group("op"), val))
    return Condition(text, tuple(terms), option)


def _number(s: str) -> float | None:
    try:
        return float(s)
    except ValueError:
        return None


def _term_mask(path: Path, cond: Condition, term: Term, col: Column) -> NDArray[np.bool_]:
    op, val = term.op, term.value
    if op == "~":
        rx = re.compile(val)
        cells = col if col.dtype.kind in "US" else np.char.mod("%.15g", col)
        return np.fromiter((rx.search(str(c)) is not None for c in cells), bool, len(cells))
    num = _number(val)
    if col.dtype.kind in "US":
        if op in ("==", "!="):
            eq = col == val
            return eq if op == "==" else ~eq
        bad = next((i for i, c in enumerate(col) if _number(str(c)) is None), 0)
        raise LogFormatError(
            f"{path}: {cond}: column {term.column!r}, row {bad + 1}: expected numbers for "
            f"{op!r}, found text {str(col[bad])!r} (use == or ~ on text)"
        )
    if num is None:
        raise LogFormatError(
            f"{path}: {cond}: column {term.column!r} holds numbers: expected a number after "
            f"{op!r}, found {val!r}"
        )
    x = np.asarray(col, dtype=np.float64)
    with np.errstate(invalid="ignore"):
        out: NDArray[np.bool_] = {
            "==": x == num,
            "!=": x != num,
            "<": x < num,
            "<=": x <= num,
            ">": x > num,
            ">=": x >= num,
        }[op]
    return out


def condition_mask(
    path: Path, cond: Condition, columns: Mapping[str, Column], n: int
) -> NDArray[np.bool_]:
    """Rows (of ``n``) where every term of ``cond`` holds.

    Raises
    ------
    LogFormatError
        If a column does not exist (naming the columns found) or an operator does not
        fit the column's content.
    """
    mask = np.ones(n, dtype=bool)
    for term in cond.terms:
        if term.column not in columns:
            raise LogFormatError(
                f"{path}: {cond}: column {term.column!r} does not exist; found "
                f"{', '.join(sorted(columns))}"
            )
        mask &= _term_mask(path, cond, term, columns[term.column])
    return mask


def repeat_mask(
    path: Path, patterns: str, columns: Mapping[str, Column], n: int
) -> NDArray[np.bool_]:
    """Rows whose every column named by ``patterns`` equals the previous row's.

    ``patterns`` is a comma-separated list of column names or shell-style patterns
    (``X1_*,Y1_*``). A sample repeated in every one of those columns is a stale copy
    from the logger, not a new reading of the machine.
    """
    names = [
        c for c in columns if any(fnmatch.fnmatchcase(c, p.strip()) for p in patterns.split(","))
    ]
    if not names:
        raise LogFormatError(
            f"{path}: --drop-repeats {patterns!r}: expected column names or patterns that "
            f"match columns; found {', '.join(sorted(columns))}"
        )
    rep = np.zeros(n, dtype=bool)
    if n > 1:
        same = np.ones(n - 1, dtype=bool)
        for c in names:
            v = columns[c]
            same &= v[1:] == v[:-1]
        rep[1:] = same
    return rep


@dataclass(frozen=True)
class RowSelection:
    """Which rows of a log to use, and rows that mark phases of it.

    Attributes
    ----------
    keep : tuple of Condition
        A row is used only if it satisfies every one of these (``--keep``).
    drop : tuple of Condition
        A row satisfying any of these is left out (``--drop``).
    drop_repeats : str or None
        Column names/patterns; a row repeating the previous row in all of them is left
        out (``--drop-repeats``).
    phases : dict of str to Condition
        Named row masks over the rows used (e.g. ``nominal``: rows to fit the nominal
        model on; ``load``: rows where a load acts).
    """

    keep: tuple[Condition, ...] = ()
    drop: tuple[Condition, ...] = ()
    drop_repeats: str | None = None
    phases: dict[str, Condition] = field(default_factory=dict)

    @property
    def empty(self) -> bool:
        """True when every row is used and no phase is marked."""
        return not (self.keep or self.drop or self.drop_repeats or self.phases)

    @classmethod
    def from_options(
        cls,
        keep: Sequence[str] = (),
        drop: Sequence[str] = (),
        drop_repeats: str | None = None,
        phases: Mapping[str, str | None] | None = None,
    ) -> RowSelection:
        """Parse the command-line texts (``phases``: option name -> condition text)."""
        ph = {
            name: parse_condition(text, f"--{name.replace('_', '-')}")
            for name, text in (phases or {}).items()
            if text is not None
        }
        return cls(
            tuple(parse_condition(k, "--keep") for k in keep),
            tuple(parse_condition(d, "--drop") for d in drop),
            drop_repeats,
            ph,
        )


class LeftOut(TypedDict):
    """How many rows one selection rule newly left out."""

    rule: str
    left_out: int


@dataclass(frozen=True)
class Selected:
    """The outcome of a selection: rows used, and how many each rule left out."""

    used: NDArray[np.bool_]
    left_out: list[LeftOut]
    phases: dict[str, NDArray[np.bool_]]


def select_rows(path: Path, sel: RowSelection, columns: Mapping[str, Column], n: int) -> Selected:
    """Apply ``sel`` to ``n`` rows; count the rows each rule newly leaves out."""
    used = np.ones(n, dtype=bool)
    left: list[LeftOut] = []

    def apply(rule: str, out: NDArray[np.bool_]) -> None:
        newly = out & used
        left.append({"rule": rule, "left_out": int(newly.sum())})
        used[newly] = False

    for c in sel.keep:
        apply(str(c), ~condition_mask(path, c, columns, n))
    for c in sel.drop:
        apply(str(c), condition_mask(path, c, columns, n))
    if sel.drop_repeats:
        apply(
            f"--drop-repeats {sel.drop_repeats!r}",
            repeat_mask(path, sel.drop_repeats, columns, n),
        )
    if not used.any():
        counts = ", ".join(f"{d['left_out']} by {d['rule']}" for d in left)
        raise LogFormatError(
            f"{path}: the row selection leaves no row: expected at least one of {n} rows; "
            f"left out {counts}"
        )
    phases = {name: condition_mask(path, c, columns, n)[used] for name, c in sel.phases.items()}
    return Selected(used, left, phases)
