"""Measured logs: read and check them (CSV + JSON sidecar, MATLAB ``.mat``), write them.

The format is docs/design.md's "Measured log": a CSV with a header row, one sample per row,
uniform sampling, SI units, and an optional JSON sidecar with the same stem. Other
tables come in through a column map, ``COL=EXPR`` with ``EXPR`` one of ``name``,
``name*scale`` or ``name*scale+offset`` (``scale`` a number or, in a ``.mat`` file, the
name of a scalar variable, e.g. ``tau_m=vir*gtau``). The map is parsed by a regular
expression, never evaluated.

A sidecar (or ``--meta``) with ``axes`` describes a machine (``common/machine.schema.json``,
issue 30): the log then keeps every column its signals name (any column name; ``t`` or
the description's ``sample_time`` for time), each axis' required signals must be there,
an optional one may be absent or hold NaN, and ``MeasuredLog.description`` holds the
machine. A sidecar without ``axes`` is the one-axis log of the design's table
(``MeasuredLog.machine`` reads it as :func:`common.machine_description.from_legacy`).

Every check failure raises :class:`server.errors.LogFormatError` with a message naming
the file, the column or row, and what was expected against what was found.
"""

from __future__ import annotations

import itertools
import json
import math
import os
import re
import tempfile
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from common.arrays import F64
from common.machine_description import (
    DescriptionError,
    MachineDescription,
    from_dict,
    from_legacy,
    is_legacy,
)
from server.errors import LogFormatError
from server.records.row_select import Column, LeftOut, RowSelection, select_rows

REQUIRED_COLUMNS: tuple[str, ...] = ("t", "tau_m", "q_m")
OPTIONAL_COLUMNS: tuple[str, ...] = ("q_l", "f_ext", "i_m", "qd_m", "qdd_m")
#: the CNC's identities per sample, optional: tool number, G-code line (the program
#: block), feed override (1 = 100 %); the program's name is the sidecar key ``program``
IDENTITY_COLUMNS: tuple[str, ...] = ("tool", "line", "override")
EFFORT_UNITS: frozenset[str] = frozenset({"N", "N m", "Nm", "N*m", "A"})
POSITION_UNITS: frozenset[str] = frozenset({"m", "rad"})
KINDS: tuple[str, ...] = ("rigid", "two_inertia")

#: relative deviation of one sampling interval from the median tolerated as jitter
JITTER_TOLERANCE = 0.05
#: an interval longer than this many median intervals is a gap (missing samples)
GAP_FACTOR = 1.5
#: rows read per chunk (and per progress-bar step) for CSV files
_CHUNK_ROWS = 200_000

_NUM = r"[-+]?(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?"
_NAME = r"[A-Za-z_][A-Za-z0-9_]*"
_MAP_RE = re.compile(
    rf"^\s*(?P<col>{_NAME})\s*=\s*(?P<src>{_NAME})"
    rf"(?:\s*\*\s*(?P<scale>{_NUM}|{_NAME}))?"
    rf"(?:\s*(?P<sign>[-+])\s*(?P<offset>\d+\.?\d*(?:[eE][-+]?\d+)?|\.\d+(?:[eE][-+]?\d+)?))?\s*$"
)


@dataclass(frozen=True)
class ColumnMap:
    """One ``COL=EXPR`` entry: ``column = source * scale + offset``."""

    column: str
    source: str
    scale: float | str = 1.0
    offset: float = 0.0

    def __str__(self) -> str:
        return f"{self.column}={self.source}*{self.scale}{self.offset:+g}"


def parse_map(text: str) -> ColumnMap:
    """Parse ``COL=EXPR`` (``name``, ``name*scale``, ``name*scale+offset``) strictly.

    Raises
    ------
    LogFormatError
        If ``text`` is not of that form (nothing is evaluated).
    """
    m = _MAP_RE.match(text)
    if m is None:
        raise LogFormatError(
            f"--map {text!r}: expected COL=name, COL=name*scale or COL=name*scale+offset "
            "(scale and offset numbers; scale may name a scalar variable of a .mat file)"
        )
    scale_txt = m.group("scale")
    scale: float | str = 1.0
    if scale_txt is not None:
        scale = scale_txt if re.fullmatch(_NAME, scale_txt) else float(scale_txt)
    offset = 0.0
    if m.group("offset") is not None:
        offset = float(m.group("offset")) * (-1.0 if m.group("sign") == "-" else 1.0)
    return ColumnMap(m.group("col"), m.group("src"), scale, offset)


@dataclass(frozen=True)
class MeasuredLog:
    """A checked measured log.

    Attributes
    ----------
    path : Path
        The file read.
    columns : dict of str to ndarray
        Canonical columns (``t``, ``tau_m``, ``q_m`` and any of ``q_l``, ``f_ext``), SI,
        and the CNC's identities when recorded (``tool``, ``line``, ``override``; the
        program is ``sidecar["program"]``).
    sample_time : float
        Median sampling interval [s].
    units : dict
        ``{"effort": ..., "position": ...}`` as declared.
    kind : str or None
        ``rigid`` or ``two_inertia`` when declared.
    nominal : dict
        Known parameters from the sidecar (may be empty).
    sidecar : dict
        The merged sidecar (file, then ``meta`` overrides).
    rows : ndarray of int, optional
        The file's 1-based data row of each sample used (None: all rows, in order).
    n_read : int
        Rows read from the file (before any selection).
    left_out : list of dict
        ``{"rule": ..., "left_out": count}`` for each row-selection rule, in order.
    phases : dict of str to ndarray of bool
        Named masks over the samples used (``nominal``, ``load``, ...).
    """

    path: Path
    columns: dict[str, F64]
    sample_time: float
    units: dict[str, str]
    kind: str | None
    nominal: dict[str, float] = field(default_factory=dict)
    sidecar: dict[str, Any] = field(default_factory=dict)
    rows: NDArray[np.int64] | None = None
    n_read: int = 0
    left_out: list[LeftOut] = field(default_factory=list)
    phases: dict[str, NDArray[np.bool_]] = field(default_factory=dict)
    #: the machine the sidecar describes (its ``axes``); None for a one-axis log of the
    #: older sidecar (see :attr:`machine`)
    description: MachineDescription | None = None

    @property
    def machine(self) -> MachineDescription:
        """The machine of this log: its description, or the one axis of an older sidecar.

        Raises
        ------
        LogFormatError
            An older sidecar that does not describe a machine (e.g. a rate outside
            10 Hz-10 kHz), naming the key.
        """
        if self.description is not None:
            return self.description
        side = {
            "sample_time": self.sample_time,
            "units": self.units,
            "kind": self.kind,
            "nominal": self.nominal,
            "encoder_resolution": self.sidecar.get("encoder_resolution"),
        }
        try:
            return from_legacy(side, self.columns)
        except DescriptionError as exc:
            raise LogFormatError(f"{self.path}: {exc}") from None

    @property
    def n(self) -> int:
        """Number of samples."""
        return len(self.columns["t"])

    @property
    def row_numbers(self) -> NDArray[np.int64]:
        """The file's 1-based data row of each sample used (all rows when none left out)."""
        if self.rows is None:
            return np.arange(1, self.n + 1)
        return self.rows

    @property
    def segments(self) -> NDArray[np.int64]:
        """Start index of each run of consecutive file rows among the samples used.

        One segment (``[0]``) when no row was left out; a row selection splits the
        record where it left rows out, and nothing may differentiate or filter across.
        """
        r = self.row_numbers
        return np.concatenate(([0], np.flatnonzero(np.diff(r) > 1) + 1)).astype(np.int64)

    def __getitem__(self, name: str) -> F64:
        return self.columns[name]


def _read_sidecar(path: Path) -> dict[str, Any]:
    side = path.with_suffix(".json")
    if not side.exists() or side == path:
        return {}
    try:
        data = json.loads(side.read_bytes().decode("utf-8"))
    except UnicodeDecodeError as exc:
        raise LogFormatError(f"{side}: not UTF-8 text ({exc.reason} at byte {exc.start})") from None
    except json.JSONDecodeError as exc:
        raise LogFormatError(f"{side}: not valid JSON ({exc})") from exc
    except RecursionError:
        raise LogFormatError(f"{side}: JSON nested too deeply (expected a flat object)") from None
    check_sidecar(side, data)
    return data


def check_sidecar(side: Path, data: Any) -> None:
    """Refuse a sidecar whose known keys have the wrong type (the loader's later checks
    assume these types), naming the key, the expected and the found.

    Raises
    ------
    LogFormatError
        Not an object; ``units`` not an object of strings; ``sample_time`` not a finite
        number > 0; ``nominal`` not an object; ``kind`` not a string.
    """
    if not isinstance(data, dict):
        raise LogFormatError(f"{side}: expected a JSON object, found {type(data).__name__}")

    def bad(key: str, expected: str, v: Any) -> LogFormatError:
        return LogFormatError(
            f"{side}: sidecar {key!r}: expected {expected}, found {type(v).__name__} {repr(v)[:60]}"
        )

    units = data.get("units")
    if units is not None and not (
        isinstance(units, dict) and all(isinstance(v, str) for v in units.values())
    ):
        raise bad("units", 'an object of unit names ({"effort": "N m", ...})', units)
    ts = data.get("sample_time")
    if ts is not None:
        ok = isinstance(ts, int | float) and not isinstance(ts, bool)
        if not (ok and ts < 1e300 and math.isfinite(float(ts)) and ts > 0):
            raise bad("sample_time", "a finite number of seconds > 0", ts)
    if data.get("nominal") is not None and not isinstance(data["nominal"], dict):
        raise bad("nominal", "an object of numbers", data["nominal"])
    if data.get("kind") is not None and not isinstance(data["kind"], str):
        raise bad("kind", "a string", data["kind"])


def _sidecar_maps(p: Path, sidecar: Mapping[str, Any]) -> list[ColumnMap]:
    """The sidecar's ``maps``: column maps as ``--map`` takes them, applied before the
    command line's (so a ``--map`` of the same column wins)."""
    raw = sidecar.get("maps")
    if raw is None:
        return []
    if not isinstance(raw, list) or not all(isinstance(m, str) for m in raw):
        raise LogFormatError(
            f"{p}: sidecar 'maps': expected a list of COL=EXPR strings, found {raw!r:.80}"
        )
    out = []
    for i, text in enumerate(raw):
        try:
            out.append(parse_map(text))
        except LogFormatError as exc:
            raise LogFormatError(f"{p}: sidecar 'maps[{i}]': {exc}") from None
    return out


def load_meta(text: str | os.PathLike[str] | None) -> dict[str, Any]:
    """Read ``--meta``: a JSON file path, or an inline JSON object starting with ``{``."""
    if text is None:
        return {}
    s = str(text)
    src = "--meta"
    try:
        if s.lstrip().startswith("{"):
            data = json.loads(s)
        else:
            p = Path(s)
            if not p.exists():
                raise LogFormatError(
                    f"--meta {s}: no such file (expected a JSON file or an inline JSON object)"
                )
            src = str(p)
            data = json.loads(p.read_text())
    except json.JSONDecodeError as exc:
        raise LogFormatError(f"{src}: not valid JSON ({exc})") from exc
    if not isinstance(data, dict):
        raise LogFormatError(f"{src}: expected a JSON object, found {type(data).__name__}")
    return data


def _read_csv(path: Path, progress: bool) -> dict[str, Column]:
    try:
        return _read_csv_text(path, progress)
    except UnicodeDecodeError as exc:
        raise LogFormatError(
            f"{path}: not UTF-8 text ({exc.reason} at byte {exc.start} of a block; expected "
            "comma-separated numbers in UTF-8 or ASCII)"
        ) from None


def _read_csv_text(path: Path, progress: bool) -> dict[str, Column]:
    # newline="": universal newlines for reading, so CR-only, LF and CRLF files split
    # into the same rows (line ends are stripped from each cell below)
    with path.open("r", newline="", encoding="utf-8") as fh:
        header_line = fh.readline()
        if not header_line.strip():
            raise LogFormatError(f"{path}: empty file (expected a header row)")
        header = [h.strip() for h in header_line.strip().split(",")]
        if len(set(header)) != len(header) or any(not h for h in header):
            raise LogFormatError(
                f"{path}: header {header}: expected unique, non-empty column names"
            )
        try:
            size = os.path.getsize(path)
        except OSError:  # pragma: no cover
            size = 0
        bar = None
        if progress and size > 20_000_000:
            from tqdm import tqdm

            bar = tqdm(total=size, unit="B", unit_scale=True, desc=f"reading {path.name}")
        chunks: list[list[Column]] = []
        row0 = 0
        while True:
            lines = [ln for ln in itertools.islice(fh, _CHUNK_ROWS) if ln.strip()]
            if not lines:
                break
            chunks.append(_parse_block(path, header, lines, row0))
            row0 += len(lines)
            if bar is not None:
                bar.update(sum(len(ln) for ln in lines))
        if bar is not None:
            bar.close()
    if not chunks:
        raise LogFormatError(f"{path}: no data rows after the header")
    out: dict[str, Column] = {}
    for j, h in enumerate(header):
        parts = [c[j] for c in chunks]
        if all(p.dtype.kind == "f" for p in parts):
            out[h] = np.ascontiguousarray(np.concatenate(parts), dtype=np.float64)
        else:  # a text column (a label): numbers of other chunks back to text
            out[h] = np.concatenate(
                [p if p.dtype.kind in "US" else np.char.mod("%.17g", p) for p in parts]
            ).astype(np.str_)
    return out


def _parse_block(path: Path, header: list[str], lines: list[str], row0: int) -> list[Column]:
    """Columns of one block of rows: floats where every cell is a number, else text."""
    ncol = len(header)
    try:
        arr = np.loadtxt(lines, delimiter=",", dtype=np.float64, ndmin=2)
        if arr.shape[1] == ncol:
            return [np.ascontiguousarray(arr[:, j]) for j in range(ncol)]
    except ValueError:
        pass
    rows: list[list[str]] = []
    for i, line in enumerate(lines):
        cells = line.rstrip("\r\n").split(",")
        row = row0 + i + 1
        if len(cells) != ncol:
            raise LogFormatError(
                f"{path}: row {row} (line {row + 1}): expected {ncol} cells "
                f"({', '.join(header)}), found {len(cells)}"
            )
        rows.append([c.strip() for c in cells])
    cols: list[Column] = []
    for j in range(ncol):
        cells_j = [r[j] for r in rows]
        try:
            cols.append(np.array(cells_j, dtype=np.float64))
        except ValueError:
            cols.append(np.array(cells_j, dtype=np.str_))
    return cols


def _numeric(path: Path, name: str, col: Column, row0: int = 0) -> F64:
    """``col`` as floats, or a refusal naming its first cell that is not a number."""
    if col.dtype.kind == "f":
        return col  # type: ignore[return-value]
    for i, c in enumerate(col):
        try:
            float(c)
        except ValueError:
            row = row0 + i + 1
            raise LogFormatError(
                f"{path}: row {row} (line {row + 1}), column {name!r}: "
                f"expected a number, found {str(c)!r}"
            ) from None
    return np.asarray(col, dtype=np.float64)  # pragma: no cover


def _read_mat(path: Path) -> dict[str, Any]:
    import scipy.io

    try:
        raw = scipy.io.loadmat(str(path))
    except NotImplementedError as exc:
        raise LogFormatError(
            f"{path}: MATLAB v7.3 (HDF5) files are not supported; save with -v7 or export a CSV"
        ) from exc
    except (ValueError, OSError, TypeError, scipy.io.matlab.MatReadError) as exc:
        raise LogFormatError(f"{path}: not a readable MATLAB .mat file ({exc})") from exc
    return {k: v for k, v in raw.items() if not k.startswith("__")}


def _as_vector(path: Path, name: str, value: Any) -> F64:
    try:
        arr = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError):
        raise LogFormatError(
            f"{path}: variable {name!r}: expected a numeric vector, found {type(value).__name__}"
        ) from None
    if arr.ndim == 2 and 1 in arr.shape:
        arr = arr.ravel()
    if arr.ndim != 1:
        raise LogFormatError(
            f"{path}: variable {name!r}: expected a vector, found shape {arr.shape}"
        )
    return np.ascontiguousarray(arr)


def _apply_maps(
    path: Path,
    source: Mapping[str, Any],
    maps: Sequence[ColumnMap],
    is_mat: bool,
    keep: set[str] | None = None,
) -> dict[str, F64]:
    """The file's numeric columns and the mapped ones (``keep``: text columns of these
    names are read as numbers too; default the log format's own columns)."""
    kind = "variable" if is_mat else "column"
    out: dict[str, F64] = {}
    canonical = set(keep) | {"t"} if keep is not None else {
        *REQUIRED_COLUMNS, *OPTIONAL_COLUMNS, *IDENTITY_COLUMNS
    }  # fmt: skip
    for name, value in source.items():
        v = np.asarray(value)
        if v.dtype.kind in "US":
            # a text column: ignored unless it is one of the log's own columns
            if name in canonical:
                out[name] = _numeric(path, name, v)
        elif v.size > 1:
            out[name] = _as_vector(path, name, value)
    for m in maps:
        if m.source not in source:
            raise LogFormatError(
                f"{path}: --map {m.column}=...: {kind} {m.source!r} does not "
                f"exist; found {', '.join(sorted(source))}"
            )
        raw = np.asarray(source[m.source])
        if raw.dtype.kind in "US":
            raw = _numeric(path, m.source, raw)
        base = _as_vector(path, m.source, raw)
        if isinstance(m.scale, str):
            if m.scale not in source:
                raise LogFormatError(
                    f"{path}: --map {m.column}=...: scale {kind} {m.scale!r} "
                    f"does not exist; found {', '.join(sorted(source))}"
                )
            sv = np.asarray(source[m.scale], dtype=np.float64)
            if sv.size != 1:
                raise LogFormatError(
                    f"{path}: --map {m.column}=...: scale {kind} {m.scale!r}: "
                    f"expected a scalar, found shape {sv.shape}"
                )
            scale = float(sv.ravel()[0])
        else:
            scale = float(m.scale)
        out[m.column] = base * scale + m.offset
    return out


def check_time(path: Path, t: F64, declared: float | None = None) -> float:
    """Check that ``t`` is strictly increasing and uniform; return the sampling interval.

    Jitter up to :data:`JITTER_TOLERANCE` of the median interval is tolerated; an
    interval above :data:`GAP_FACTOR` times the median is a gap and is refused, naming
    the row (1-based data row, the header being line 1).
    """
    if len(t) < 2:
        raise LogFormatError(f"{path}: column 't': expected at least 2 samples, found {len(t)}")
    dt = np.diff(t)
    bad = np.flatnonzero(~(dt > 0))
    if bad.size:
        i = int(bad[0])
        raise LogFormatError(
            f"{path}: column 't', row {i + 2}: time not increasing "
            f"(t = {float(t[i + 1])!r} after {float(t[i])!r})"
        )
    ts = float(np.median(dt))
    gap = np.flatnonzero(dt > GAP_FACTOR * ts)
    if gap.size:
        i = int(gap[0])
        raise LogFormatError(
            f"{path}: column 't', row {i + 2}: gap of {dt[i]:.6g} s after "
            f"t = {t[i]:.6g} s (expected uniform sampling every {ts:.6g} s; "
            "missing samples?)"
        )
    jit = np.flatnonzero(np.abs(dt - ts) > JITTER_TOLERANCE * ts)
    if jit.size:
        i = int(jit[0])
        raise LogFormatError(
            f"{path}: column 't', row {i + 2}: interval {dt[i]:.6g} s "
            f"(expected {ts:.6g} s within {JITTER_TOLERANCE:.0%} jitter)"
        )
    if declared is not None:
        d = float(declared)
        if not (math.isfinite(d) and d > 0 and abs(d - ts) <= JITTER_TOLERANCE * ts):
            raise LogFormatError(
                f"{path}: sidecar sample_time = {declared!r} s, but column 't' "
                f"is sampled every {ts:.6g} s"
            )
    return ts


def load_log(
    path: str | os.PathLike[str],
    *,
    meta: Mapping[str, Any] | None = None,
    maps: Iterable[str | ColumnMap] = (),
    kind: str | None = None,
    required: Sequence[str] = REQUIRED_COLUMNS,
    progress: bool = False,
    selection: RowSelection | None = None,
    current_ok: bool = False,
) -> MeasuredLog:
    """Read a measured log and check it against the log format (docs/design.md).

    Parameters
    ----------
    path : path-like
        ``.csv`` (with an optional ``.json`` sidecar of the same stem) or ``.mat``.
    meta : mapping, optional
        Sidecar keys overriding the file's sidecar (``--meta``).
    maps : iterable of str or ColumnMap
        Column map entries ``COL=EXPR`` (``--map``).
    kind : str, optional
        ``rigid`` or ``two_inertia``; overrides the sidecar's ``kind``.
    required : sequence of str
        Columns that must be present after mapping.
    progress : bool
        Show a progress bar while reading long files.
    selection : RowSelection, optional
        Rows to use (``--keep``, ``--drop``, ``--drop-repeats``) and phase masks; the
        rows each rule leaves out are counted in ``MeasuredLog.left_out``.
    current_ok : bool
        Accept an effort in A without a torque constant (kept in A); otherwise
        ``units.effort = "A"`` needs ``nominal.K_t``.

    Returns
    -------
    MeasuredLog

    Raises
    ------
    LogFormatError
        On any deviation from the format, naming file, column or row.
    """
    p = Path(path)
    if not p.exists():
        raise LogFormatError(f"{p}: no such file (expected a .csv or .mat log)")
    sidecar = _read_sidecar(p)
    sidecar.update(dict(meta or {}))
    parsed = [
        *_sidecar_maps(p, sidecar),
        *(m if isinstance(m, ColumnMap) else parse_map(m) for m in maps),
    ]
    source, is_mat = _read_source(p, progress)
    if not is_legacy(sidecar):
        return _load_described(p, sidecar, source, parsed, is_mat, selection)
    cols = _apply_maps(p, source, parsed, is_mat)

    units = _declared_units(p, sidecar)
    nominal = _nominal(p, sidecar)
    units = _effort_as_torque(p, cols, units, nominal, current_ok)

    declared = sidecar.get("sample_time")
    _time_from_sample_time(p, cols, declared)
    keep, n = _kept_columns(p, cols, required)
    ts = check_time(p, cols["t"], None if declared is None else declared)

    used, left_out, phases = _selected(p, selection, source, cols, keep, n)
    rows = np.flatnonzero(used)
    out = _used_columns(p, cols, keep, rows, n)
    prog = sidecar.get("program")
    if prog is not None and (not isinstance(prog, str) or not 1 <= len(prog) <= 32):
        raise LogFormatError(
            f"{p}: sidecar 'program': expected a name of 1-32 characters, found {prog!r}"
        )

    k = kind if kind is not None else sidecar.get("kind")
    if k is not None and k not in KINDS:
        raise LogFormatError(f"{p}: kind {k!r}: expected one of {', '.join(KINDS)}")
    return MeasuredLog(
        p, out, ts, dict(units), k, nominal, sidecar,
        rows=rows + 1, n_read=n, left_out=left_out, phases=phases,
    )  # fmt: skip


def _load_described(
    p: Path,
    sidecar: dict[str, Any],
    source: Mapping[str, Any],
    maps: Sequence[ColumnMap],
    is_mat: bool,
    selection: RowSelection | None,
) -> MeasuredLog:
    """A log whose sidecar describes a machine: every column its signals name, checked."""
    try:
        machine = from_dict(sidecar)
    except DescriptionError as exc:
        raise LogFormatError(f"{p}: sidecar: {exc}") from None
    wanted = machine.sources()
    cols = _apply_maps(p, source, maps, is_mat, keep=set(wanted))
    _time_from_sample_time(p, cols, machine.sample_time, first=next(iter(wanted)))
    missing = [
        f"{s.source!r} ({s.owner}.{s.role})"
        for a in machine.axes
        for s in machine.signals()
        if s.owner == a.name and s.role in a.required_roles and s.source not in cols
    ]
    if missing:
        raise LogFormatError(
            f"{p}: missing column(s) {', '.join(missing)}, which the machine description "
            f"requires; found {', '.join(sorted(cols)) or 'none'} (map one with --map COL=EXPR)"
        )
    keep = ["t", *(c for c in wanted if c in cols)]
    n = len(cols["t"])
    for c in keep:
        if len(cols[c]) != n:
            raise LogFormatError(
                f"{p}: column {c!r}: expected {n} samples (as 't'), found {len(cols[c])}"
            )
    ts = check_time(p, cols["t"], machine.sample_time)
    used, left_out, phases = _selected(p, selection, source, cols, keep, n)
    rows = np.flatnonzero(used)
    required = {s.source for a in machine.axes for s in machine.signals()
                if s.owner == a.name and s.role in a.required_roles}  # fmt: skip
    identities = {src: role for role, src in machine.identities.items() if role != "program"}
    out = _used_columns(p, cols, keep, rows, n, finite={"t", *required}, identities=identities)
    ax = machine.axes[0]
    return MeasuredLog(
        p, out, ts, {"effort": ax.effort_unit, "position": ax.position_unit},
        ax.kind if len(machine.axes) == 1 else None, dict(ax.nominal), sidecar,
        rows=rows + 1, n_read=n, left_out=left_out, phases=phases, description=machine,
    )  # fmt: skip


def _read_source(p: Path, progress: bool) -> tuple[Mapping[str, Any], bool]:
    """The file's columns (``.csv``) or variables (``.mat``), and whether it is a ``.mat``."""
    suffix = p.suffix.lower()
    if suffix == ".mat":
        source: Mapping[str, Any] = _read_mat(p)
        is_mat = True
    elif suffix in (".csv", ".txt"):
        source = _read_csv(p, progress)
        is_mat = False
    else:
        raise LogFormatError(f"{p}: unknown file type {p.suffix!r} (expected .csv or .mat)")
    return source, is_mat


def _declared_units(p: Path, sidecar: Mapping[str, Any]) -> dict[str, Any]:
    """The sidecar's ``units``, checked: an effort and a position unit of the format."""
    units = sidecar.get("units")
    if not isinstance(units, dict) or "effort" not in units or "position" not in units:
        raise LogFormatError(
            f"{p}: units not declared: expected sidecar key 'units' = "
            '{"effort": "N" | "N m" | "A", "position": "m" | "rad"} '
            f"(in {p.with_suffix('.json').name} or --meta), found {units!r}"
        )
    if units["effort"] not in EFFORT_UNITS:
        raise LogFormatError(
            f"{p}: units.effort = {units['effort']!r}: expected one of {sorted(EFFORT_UNITS)}"
        )
    if units["position"] not in POSITION_UNITS:
        raise LogFormatError(
            f"{p}: units.position = {units['position']!r}: expected one of {sorted(POSITION_UNITS)}"
        )
    return units


def _nominal(p: Path, sidecar: Mapping[str, Any]) -> dict[str, float]:
    """The sidecar's ``nominal`` parameters, each a finite number."""
    nominal_raw = sidecar.get("nominal", {}) or {}
    if not isinstance(nominal_raw, dict):
        raise LogFormatError(
            f"{p}: sidecar 'nominal': expected an object, found {type(nominal_raw).__name__}"
        )
    nominal: dict[str, float] = {}
    for k, v in nominal_raw.items():
        if not isinstance(v, int | float) or not math.isfinite(float(v)):
            raise LogFormatError(f"{p}: sidecar nominal.{k} = {v!r}: expected a finite number")
        nominal[k] = float(v)
    return nominal


def _effort_as_torque(
    p: Path,
    cols: dict[str, F64],
    units: dict[str, Any],
    nominal: Mapping[str, float],
    current_ok: bool,
) -> dict[str, Any]:
    """Effort given as current: ``tau_m = K_t * i_m`` in ``cols`` when ``K_t`` is known
    (the units returned then say N m), else kept in A when ``current_ok``."""
    if units["effort"] == "A":
        if "tau_m" not in cols and "i_m" in cols:
            cols["tau_m"] = cols["i_m"]
        if "K_t" in nominal:
            if "tau_m" in cols:
                cols["tau_m"] = cols["tau_m"] * nominal["K_t"]
            units = {**units, "effort": "N m"}
        elif not current_ok:
            raise LogFormatError(
                f"{p}: units.effort = 'A' (current): expected nominal.K_t "
                "[N m/A] in the sidecar, found none"
            )
    return units


def _time_from_sample_time(
    p: Path, cols: dict[str, F64], declared: Any, first: str | None = None
) -> None:
    """No time column but a declared ``sample_time``: a uniform ``t`` added to ``cols``
    (as long as column ``first``, default the first of the log format's present)."""
    if "t" not in cols and declared is not None:
        # no time column: rows are uniform, one every sample_time seconds
        if not (isinstance(declared, int | float) and math.isfinite(declared) and declared > 0):
            raise LogFormatError(
                f"{p}: sample_time = {declared!r}: expected a finite number of seconds > 0"
            )
        if first is None or first not in cols:
            first = next((c for c in (*REQUIRED_COLUMNS, *OPTIONAL_COLUMNS) if c in cols), None)
        if first is not None:
            cols["t"] = np.arange(len(cols[first]), dtype=np.float64) * float(declared)


def _kept_columns(
    p: Path, cols: Mapping[str, F64], required: Sequence[str]
) -> tuple[list[str], int]:
    """The format's columns present (the required ones checked) and their common length."""
    missing = [c for c in required if c not in cols]
    if missing:
        hint = " or declare sample_time" if "t" in missing else ""
        raise LogFormatError(
            f"{p}: missing column(s) {', '.join(missing)}; found "
            f"{', '.join(sorted(cols)) or 'none'} (map one with "
            f"--map COL=name*scale+offset{hint})"
        )
    keep = [c for c in (*REQUIRED_COLUMNS, *OPTIONAL_COLUMNS, *IDENTITY_COLUMNS) if c in cols]
    n = len(cols["t"]) if "t" in cols else len(cols[keep[0]])
    for c in keep:
        if len(cols[c]) != n:
            raise LogFormatError(
                f"{p}: column {c!r}: expected {n} samples (as 't'), found {len(cols[c])}"
            )
    return keep, n


def _selected(
    p: Path,
    selection: RowSelection | None,
    source: Mapping[str, Any],
    cols: Mapping[str, F64],
    keep: Sequence[str],
    n: int,
) -> tuple[NDArray[np.bool_], list[LeftOut], dict[str, NDArray[np.bool_]]]:
    """Rows used, each rule's count left out and the phase masks: every row unless a
    selection leaves some out (its conditions may name any column of the file)."""
    used = np.ones(n, dtype=bool)
    left_out: list[LeftOut] = []
    phases: dict[str, NDArray[np.bool_]] = {}
    if selection is not None and not selection.empty:
        where: dict[str, NDArray[Any]] = {}
        for name, value in source.items():
            a = np.asarray(value)
            a = a.ravel() if a.ndim == 2 and 1 in a.shape else a
            if a.ndim == 1 and len(a) == n:
                where[name] = a
        where.update({c: cols[c] for c in keep})
        chosen = select_rows(p, selection, where, n)
        used, left_out, phases = chosen.used, chosen.left_out, chosen.phases
    return used, left_out, phases


def _used_columns(
    p: Path,
    cols: Mapping[str, F64],
    keep: Sequence[str],
    rows: NDArray[np.intp],
    n: int,
    finite: set[str] | None = None,
    identities: Mapping[str, str] | None = None,
) -> dict[str, F64]:
    """The kept columns over the rows used, the ``finite`` ones (default all) finite, and
    the identity columns (``identities``: column -> identity; default ``tool``, ``line``,
    ``override`` by name) checked."""
    ident = {c: c for c in IDENTITY_COLUMNS} if identities is None else identities
    out: dict[str, F64] = {}
    for c in keep:
        v = cols[c][rows] if len(rows) < n else cols[c]
        checked = finite is None or c in finite
        bad = np.flatnonzero(~np.isfinite(v)) if checked else np.zeros(0, dtype=np.intp)
        if bad.size:
            i = int(rows[int(bad[0])])
            raise LogFormatError(
                f"{p}: column {c!r}, row {i + 1}: expected a finite value, "
                f"found {float(cols[c][i])}"
            )
        if c in ident:
            _check_identity(p, c, v, rows, ident[c])
        out[c] = np.ascontiguousarray(v)
    return out


def _check_identity(
    p: Path, c: str, v: F64, rows: NDArray[np.int64], role: str | None = None
) -> None:
    """Tool and line are whole numbers >= 0; the override lies in (0, 3] (``rows``: the
    file's 0-based row of each sample, for the message; ``role``: which identity column
    ``c`` holds, default its name). NaN (not known) passes."""
    known = np.isfinite(v)
    if (role or c) == "override":
        bad = np.flatnonzero(known & ~((v > 0.0) & (v <= 3.0)))
        want = "a feed override in (0, 3]"
    else:
        bad = np.flatnonzero(known & ((v < 0) | (v != np.round(v))))
        want = "a whole number >= 0"
    if bad.size:
        i = int(bad[0])
        raise LogFormatError(
            f"{p}: column {c!r}, row {int(rows[i]) + 1}: expected {want}, found {float(v[i])}"
        )


def write_log(path: Path, columns: Mapping[str, NDArray[Any]], sidecar: Mapping[str, Any]) -> None:
    """Write ``columns`` as CSV at ``path`` and ``sidecar`` as JSON beside it, atomically.

    Both files are written to temporary files in the same directory and renamed into
    place only when complete, so a failure leaves no partial output.

    Raises
    ------
    LogFormatError
        If the columns are empty, not 1-D or of unequal length, or a name is not a
        plain identifier.
    """
    p = Path(path)
    if not columns:
        raise LogFormatError(f"{p}: expected at least one column to write, found none")
    names = list(columns)
    arrays = [np.asarray(columns[c], dtype=np.float64) for c in names]
    n = len(arrays[0])
    for c, a in zip(names, arrays):
        if not re.fullmatch(_NAME, c):
            raise LogFormatError(f"{p}: column name {c!r}: expected an identifier")
        if a.ndim != 1 or len(a) != n:
            raise LogFormatError(
                f"{p}: column {c!r}: expected a 1-D array of {n} samples, found shape {a.shape}"
            )
    p.parent.mkdir(parents=True, exist_ok=True)
    side = p.with_suffix(".json")
    tmps: list[str] = []
    try:
        fd, tmp_csv = tempfile.mkstemp(prefix=f".{p.name}.", suffix=".tmp", dir=p.parent)
        tmps.append(tmp_csv)
        with os.fdopen(fd, "w", newline="") as fh:
            np.savetxt(
                fh,
                np.column_stack(arrays),
                delimiter=",",
                fmt="%.17g",
                header=",".join(names),
                comments="",
            )
        fd2, tmp_json = tempfile.mkstemp(prefix=f".{side.name}.", suffix=".tmp", dir=p.parent)
        tmps.append(tmp_json)
        with os.fdopen(fd2, "w") as fh:
            json.dump(dict(sidecar), fh, indent=2, default=float)
            fh.write("\n")
        os.replace(tmp_json, side)
        tmps.remove(tmp_json)
        os.replace(tmp_csv, p)
        tmps.remove(tmp_csv)
    finally:
        for t in tmps:
            try:
                os.unlink(t)
            except OSError:
                pass
