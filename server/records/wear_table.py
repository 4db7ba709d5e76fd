"""A table of cutting segments with flank wear: read and check it.

The table as published (``turning-wear/segments.csv``, Vicomtech, CC BY-SA 4.0) is a
Latin-1 CSV, one row per one-second segment, a ``tool`` column, the measured flank wear
``Vb`` [um] and five features per signal (``_MEAN``, ``_RMS``, ``_MAX``, ``_SK``,
``_KURT``). Other column names come in through ``--map COL=EXPR`` as in ``cutwatch
residual`` (the same parser, :func:`server.records.measured_log.parse_map`; the
published names hold dots, e.g. ``TV2.Z_MEAN``, which that parser's names do not, so dots
are carried through it encoded).

Every refusal is a :class:`server.errors.LogFormatError` naming the file, the column or
row, what was expected and what was found.
"""

from __future__ import annotations

import csv
import io
import math
import re
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from common.arrays import F64
from server.errors import LogFormatError
from server.records.measured_log import ColumnMap, parse_map

#: the signals ``cutwatch wear`` offers: name -> column prefix in the published table
SIGNALS: dict[str, str] = {"feed_force": "F_f", "drive_torque": "TV2.Z", "drive_current": "CV3.Z"}
#: the five features of each signal
FEATURES: tuple[str, ...] = ("MEAN", "RMS", "MAX", "SK", "KURT")
#: programmed feed rate (CNC units, not documented)
FEED = "CON.G.FREAL"
TOOL = "tool"
VB = "Vb"
_DOT = "_D0T_"


def parse_wear_map(text: str) -> ColumnMap:
    """``COL=EXPR`` as :func:`parse_map` reads it, with dots allowed in both names."""
    enc = re.sub(r"[A-Za-z_][A-Za-z0-9_.]*", lambda m: m.group(0).replace(".", _DOT), text.strip())
    m = parse_map(enc)
    scale = m.scale.replace(_DOT, ".") if isinstance(m.scale, str) else m.scale
    if isinstance(scale, str):
        raise LogFormatError(f"--map {text!r}: the scale must be a number in a CSV table")
    return ColumnMap(m.column.replace(_DOT, "."), m.source.replace(_DOT, "."), scale, m.offset)


@dataclass(frozen=True)
class WearTable:
    """The checked columns of a wear table.

    Attributes
    ----------
    path : Path
    columns : dict of str to ndarray
        Every numeric column that was asked for, canonical names (after ``--map``).
    tools : list of int
        Tool numbers in order of first appearance.
    has_vb : bool
        Whether the table has measured VB.
    """

    path: Path
    columns: dict[str, F64]
    tools: list[int]
    has_vb: bool

    def rows_of(self, tool: int) -> np.ndarray:
        """Row indices of one tool (in table order = order of its life)."""
        return np.flatnonzero(self.columns[TOOL] == tool)

    def column(self, name: str, tool: int | None = None) -> F64:
        c = self.columns[name]
        return c if tool is None else c[self.rows_of(tool)]


def signal_columns(signal: str) -> list[str]:
    """The five feature columns of a signal (``feed_force`` -> ``F_f_MEAN``, ...)."""
    if signal not in SIGNALS:
        raise LogFormatError(f"--signal {signal!r}: expected one of {', '.join(SIGNALS)}")
    return [f"{SIGNALS[signal]}_{f}" for f in FEATURES]


def read_wear_table(
    path: str | Path,
    needed: Sequence[str],
    maps: Iterable[str] = (),
    *,
    optional: Sequence[str] = (VB,),
) -> WearTable:
    """Read the columns ``needed`` (+ ``optional`` when present) of a wear table.

    Parameters
    ----------
    path : path
        CSV, Latin-1 encoded (UTF-8 reads the same for ASCII content).
    needed : sequence of str
        Canonical column names that must be there and numeric in every row.
    maps : iterable of str
        ``COL=EXPR`` entries: canonical column ``COL`` from the table's ``EXPR``.
    optional : sequence of str
        Columns read when present (``Vb``).

    Raises
    ------
    LogFormatError
        Missing file or column, an empty or non-numeric cell (file, column, row, found).
    """
    p = Path(path)
    if not p.is_file():
        raise LogFormatError(f"{p}: no such file (expected a CSV wear table)")
    parsed = {m.column: m for m in (parse_wear_map(t) for t in maps)}
    try:
        raw = p.read_bytes().decode("latin-1")
    except OSError as exc:
        raise LogFormatError(f"{p}: cannot read: {exc}") from None
    if "\x00" in raw[:4096]:
        raise LogFormatError(f"{p}: expected a text CSV table, found binary data")
    # csv on the text itself: str.splitlines would also split at \x85 (Latin-1 NEL)
    reader = csv.reader(io.StringIO(raw, newline=""))
    try:
        header = [h.strip() for h in next(reader)]
    except StopIteration:
        raise LogFormatError(f"{p}: expected a header row, found an empty file") from None
    rows = [r for r in reader if any(c.strip() for c in r)]
    idx = {h: i for i, h in enumerate(header)}
    want = [TOOL, *needed]
    out: dict[str, F64] = {}
    for name in [*want, *optional]:
        m = parsed.get(name)
        src = m.source if m else name
        if src not in idx:
            if name in optional and name not in want:
                continue
            how = f" (mapped from {src!r})" if m else ""
            raise LogFormatError(
                f"{p}: column {name!r}{how}: expected in the header, found "
                f"{len(header)} columns: {', '.join(header[:8])}{' ...' if len(header) > 8 else ''}"
                " (map another name with --map COL=name)"
            )
        j = idx[src]
        vals = np.empty(len(rows))
        for r, row in enumerate(rows):
            cell = row[j].strip() if j < len(row) else ""
            try:
                v = float(cell)
                if not math.isfinite(v):
                    raise ValueError
            except ValueError:
                found = "an empty cell" if cell == "" else repr(cell[:20])
                raise LogFormatError(
                    f"{p}: column {src!r}, row {r + 2} (line {r + 2}): expected a finite "
                    f"number, found {found}"
                ) from None
            vals[r] = v
        scale = float(m.scale) if m else 1.0
        out[name] = vals * scale + (m.offset if m else 0.0)
    if not rows:
        raise LogFormatError(f"{p}: expected data rows after the header, found none")
    t = out[TOOL]
    bad = np.flatnonzero(t != np.round(t))
    if len(bad):
        raise LogFormatError(
            f"{p}: column {TOOL!r}, row {int(bad[0]) + 2}: expected a tool number, "
            f"found {t[bad[0]]!r}"
        )
    tools = [int(x) for x in dict.fromkeys(t.astype(int).tolist())]
    return WearTable(path=p, columns=out, tools=tools, has_vb=VB in out)


def parse_tools(text: str | None, table: WearTable, option: str) -> list[int] | None:
    """``3,5,7`` -> [3, 5, 7], each checked against the table's tools (None if not given)."""
    if text is None:
        return None
    try:
        tools = [int(x) for x in text.split(",") if x.strip()]
    except ValueError:
        raise LogFormatError(
            f"{option} {text!r}: expected tool numbers separated by commas, e.g. 3,5,7"
        ) from None
    if not tools:
        raise LogFormatError(f"{option} {text!r}: expected at least one tool number")
    unknown = [x for x in tools if x not in table.tools]
    if unknown:
        raise LogFormatError(
            f"{table.path}: {option}: tool {unknown[0]} expected in column {TOOL!r}, "
            f"found tools {', '.join(map(str, table.tools))}"
        )
    return tools


__all__ = [
    "FEATURES",
    "FEED",
    "SIGNALS",
    "TOOL",
    "VB",
    "WearTable",
    "parse_tools",
    "parse_wear_map",
    "read_wear_table",
    "signal_columns",
]
