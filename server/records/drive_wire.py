"""The broker's wire format: drive blocks in, the machine's meta, estimates out.

Three payloads travel on ``cutwatch/<machine>/...`` (docs/broker.md):

``drive`` — one block of uniformly sampled drive signals, binary::

    <header: UTF-8 JSON, one line> b"\\n" <body: the columns, one after another>

    header = {"schema": "cutwatch.drive", "version": 1, "seq": k, "t0": s,
              "sample_time": s, "n": samples,
              "columns": [{"name": "tau_m", "dtype": "<f4", "unit": "N m"}, ...]}

  The body holds each column's ``n`` values in the header's order, little-endian (``<f4``
  float32 or ``<f8`` float64 per column). Sample ``i`` is at ``t0 + i * sample_time``:
  time is uniform within a block (the measured log's contract, docs/design.md), so it
  costs no column. ``seq`` counts blocks from 0 per publisher run; with ``t0`` it reveals
  gaps, duplicates and blocks out of order. An optional ``wall`` (the publisher's clock at
  publishing, unix s) lets the receivers measure latency. Columns: ``q_m`` and one of
  ``tau_m``/``i_m`` are required; ``q_l`` and ``f_ext`` are optional. Positions should
  travel as ``<f8``: a float32 angle of 1000 rad resolves only 6e-5 rad, coarser than a
  20-bit encoder.

  Minor version 1 (``"minor": 1``; a header without ``minor`` is minor 0 and still
  accepted) adds the CNC's identities of the block, optional::

    "program": "O1001",
    "segments": [{"i": 0, "tool": 1, "line": 20, "override": 1.0},
                 {"i": 180, "tool": 1, "line": 30}]

  ``program`` is the running program's name (1-32 characters); each segment says from
  which sample ``i`` of the block on the spindle holds tool ``tool`` and the CNC runs
  G-code line ``line`` (the program block), with the feed override ``override`` (1 =
  100 %) when given. ``i`` starts at 0 and grows. A minor-0 receiver ignores these keys
  (it reads only the ones it knows), so a new publisher stays readable by old
  receivers, and old publishers by new ones.

  Minor version 2 carries every column of a machine (issue 30): a column may have any
  name its machine description gives a signal (``X_q``, ``S_speed``...; 1-200
  characters, no control character, no comma) and any unit of :data:`UNITS_ALL`. The
  decoder passes every well-formed column; :func:`check_block` then keeps the columns
  the machine description names (their units checked, the required ones finite, an
  optional one missing from a block filled with NaN) and returns the others as ignored,
  to be counted: an unknown column never costs the block. The columns of minor 0 and 1
  (``tau_m``, ``i_m``, ``q_m``, ``q_l``, ``f_ext``) keep their units wherever they travel.

``meta`` — retained JSON: the machine description (``common/machine.schema.json``:
``sample_time``, ``axes``, ``spindle``, ``identities``) as minor 1, plus ``schema`` and
``version``; a one-axis machine whose signals carry the old column names also gets the
old keys (``units``, ``kind``, ``nominal``, ``encoder_resolution``), so a receiver of
minor 0 still reads it. A meta without ``axes`` (minor 0: the log sidecar's keys) is read
as a one-axis machine (:func:`common.machine_description.from_legacy`).

``estimates`` — JSON, what the service publishes at a rate the user sets.

Every check failure raises :class:`WireError` with a ``kind`` (``schema``, ``version``,
``units``, ``shape``, ``value``) that the source counts by, and a message naming the
field, the expected and the found.
"""

from __future__ import annotations

import json
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any, NotRequired, TypedDict

import numpy as np

from common.arrays import F64
from common.machine_description import (
    DescriptionError,
    MachineDescription,
    Signal,
    describe,
    is_legacy,
)
from server.errors import CutwatchError

DRIVE_SCHEMA = "cutwatch.drive"
META_SCHEMA = "cutwatch.meta"
ESTIMATES_SCHEMA = "cutwatch.estimates"
VERSION = 1
#: the drive schema's minor version (1: the CNC identities, program and segments; 2: any
#: column a machine description names)
MINOR = 2
#: the meta's minor version (1: the machine description)
META_MINOR = 1
#: the longest program name a block may carry
MAX_PROGRAM = 32

#: the columns a drive block may carry, and the unit family of each
COLUMN_FAMILY: dict[str, str] = {
    "tau_m": "effort",
    "i_m": "current",
    "q_m": "position",
    "q_l": "position",
    "f_ext": "effort",
}
UNITS: dict[str, frozenset[str]] = {
    "effort": frozenset({"N m", "N"}),
    "current": frozenset({"A"}),
    "position": frozenset({"rad", "m"}),
}
#: every unit a column may carry (minor 2): positions, velocities, accelerations, efforts,
#: currents, the spindle's speed, power, torque and load
UNITS_ALL: frozenset[str] = frozenset(
    {"m", "rad", "m/s", "rad/s", "m/s^2", "rad/s^2", "N", "N m", "A"}
    | {"rpm", "1/s", "W", "kW", "%", ""}
)
#: a column name of minor 2 (as a machine description's source, common/machine.schema.json)
_COLUMN_NAME_MAX = 200
DTYPES: frozenset[str] = frozenset({"<f4", "<f8"})
#: a block larger than this is refused before parsing (a 50 ms block at 2.5 kHz of five
#: float64 columns is 5 kB)
MAX_PAYLOAD = 1 << 20
MAX_HEADER = 4096


class WireError(CutwatchError, ValueError):
    """A payload does not follow the wire format; ``kind`` says which check failed."""

    def __init__(self, kind: str, msg: str) -> None:
        self.kind = kind
        super().__init__(msg)


@dataclass(frozen=True)
class Segment:
    """From sample ``i`` of a block on: tool ``tool``, G-code line ``line``, feed override
    ``override`` (None when the publisher does not send it)."""

    i: int
    tool: int
    line: int
    override: float | None = None


def identity_segments(tool: Any, line: Any, override: Any) -> list[Segment]:
    """The identities of one block's samples as segments: one per run of equal values.

    ``tool`` and ``line`` are per-sample arrays (or None: not known, sent as 0) of whole
    numbers >= 0 (anything else: 0); ``override`` per sample (or None), sent only where
    it is in (0, 3]. No identity at all: no segments.
    """
    if tool is None and line is None and override is None:
        return []
    n = len(next(v for v in (tool, line, override) if v is not None))
    tl, ln = _whole_ids(tool, n), _whole_ids(line, n)
    ov = np.full(n, np.nan) if override is None else np.asarray(override, dtype=np.float64)
    key = np.column_stack([tl, ln, np.nan_to_num(ov, nan=-1.0)])
    starts = np.flatnonzero(np.r_[True, np.any(key[1:] != key[:-1], axis=1)])
    return [
        Segment(int(i), int(tl[i]), int(ln[i]), float(ov[i]) if 0 < ov[i] <= 3 else None)
        for i in starts
    ]


def _whole_ids(v: Any, n: int) -> np.ndarray:
    """A tool or line identity as whole numbers >= 0 (0: not known)."""
    if v is None:
        return np.zeros(n, dtype=np.int64)
    x = np.asarray(v, dtype=np.float64)
    ok = np.isfinite(x) & (x >= 0)
    return np.where(ok, np.round(np.where(ok, x, 0.0)), 0).astype(np.int64)


@dataclass(frozen=True)
class DriveBlock:
    """One decoded drive block."""

    seq: int
    t0: float
    sample_time: float
    columns: dict[str, F64]
    units: dict[str, str] = field(default_factory=dict)
    #: the publisher's wall clock at publishing (unix s), when it sent one
    wall: float | None = None
    #: the schema's minor version the publisher wrote (0: no identities)
    minor: int = 0
    #: the running program's name (minor 1), when sent
    program: str | None = None
    #: the CNC's identities along the block (minor 1), empty when not sent
    segments: tuple[Segment, ...] = ()

    def identities(self) -> dict[str, F64] | None:
        """Per-sample ``tool``, ``line`` and ``override`` (NaN where not sent), or None
        for a block without segments."""
        if not self.segments:
            return None
        n = self.n
        out = {k: np.full(n, np.nan) for k in ("tool", "line", "override")}
        for j, sg in enumerate(self.segments):
            end = self.segments[j + 1].i if j + 1 < len(self.segments) else n
            out["tool"][sg.i : end] = sg.tool
            out["line"][sg.i : end] = sg.line
            if sg.override is not None:
                out["override"][sg.i : end] = sg.override
        return out

    @property
    def n(self) -> int:
        return len(next(iter(self.columns.values()))) if self.columns else 0

    def tail(self, k: int) -> DriveBlock:
        """The block from its sample ``k`` on (identities shifted with it)."""
        segs: list[Segment] = []
        for j, sg in enumerate(self.segments):
            end = self.segments[j + 1].i if j + 1 < len(self.segments) else self.n
            if end > k:
                segs.append(Segment(max(sg.i - k, 0), sg.tool, sg.line, sg.override))
        return DriveBlock(
            seq=self.seq,
            t0=self.t0 + k * self.sample_time,
            sample_time=self.sample_time,
            columns={name: v[k:] for name, v in self.columns.items()},
            units=self.units,
            wall=self.wall,
            minor=self.minor,
            program=self.program,
            segments=tuple(segs),
        )

    @property
    def t(self) -> F64:
        return self.t0 + np.arange(self.n, dtype=np.float64) * self.sample_time

    @property
    def t_end(self) -> float:
        """Time of the sample after this block's last one."""
        return self.t0 + self.n * self.sample_time


def _unit_ok(name: str, unit: str) -> bool:
    """A legacy column in a unit of its family; any other column in a known unit."""
    if name in COLUMN_FAMILY:
        return unit in UNITS[COLUMN_FAMILY[name]]
    return unit in UNITS_ALL


def _name_ok(name: Any) -> bool:
    return (
        isinstance(name, str)
        and 1 <= len(name) <= _COLUMN_NAME_MAX
        and "," not in name
        and not any(ord(c) < 32 for c in name)
    )


def _expected_units(name: str) -> list[str]:
    return sorted(UNITS[COLUMN_FAMILY[name]] if name in COLUMN_FAMILY else UNITS_ALL)


def encode_drive(
    seq: int,
    t0: float,
    sample_time: float,
    columns: Mapping[str, Any],
    units: Mapping[str, str],
    dtypes: Mapping[str, str] | None = None,
    wall: float | None = None,
    program: str | None = None,
    segments: Sequence[Segment] = (),
) -> bytes:
    """Encode one drive block (see the module docstring for the format).

    ``units`` maps a unit family (``effort``, ``position``, ``current``) or a column name
    to its unit (a column of another name needs its own entry); ``dtypes`` maps a column
    to ``<f4``/``<f8`` (default: positions ``<f8``, the rest ``<f4``). ``program`` and
    ``segments`` are the CNC's identities (minor 1); columns of other names than minor
    0's make the block minor 2.
    """
    dtypes = dict(dtypes or {})
    head_cols = []
    parts = []
    n = None
    for name, values in columns.items():
        if not _name_ok(name):
            raise WireError(
                "shape", f"column {name!r}: expected a name of 1-200 characters without , "
            )
        fam = COLUMN_FAMILY.get(name, "")
        unit = units.get(name, units.get(fam, "A" if fam == "current" else ""))
        if not _unit_ok(name, unit):
            raise WireError(
                "units",
                f"column {name!r}: unit expected one of {_expected_units(name)}, got {unit!r}",
            )
        position = fam == "position" or unit in ("m", "rad")
        dt = dtypes.get(name, "<f8" if position else "<f4")
        if dt not in DTYPES:
            raise WireError("shape", f"column {name!r}: dtype expected <f4 or <f8, got {dt!r}")
        a = np.ascontiguousarray(values, dtype=dt)
        if a.ndim != 1 or (n is not None and len(a) != n):
            raise WireError("shape", f"column {name!r}: expected {n} values, got {a.shape}")
        n = len(a)
        head_cols.append({"name": name, "dtype": dt, "unit": unit})
        parts.append(a.tobytes())
    header = {
        "schema": DRIVE_SCHEMA,
        "version": VERSION,
        "seq": int(seq),
        "t0": float(t0),
        "sample_time": float(sample_time),
        "n": int(n or 0),
        "columns": head_cols,
    }
    if wall is not None:
        header["wall"] = float(wall)
    if program is not None or segments or any(c["name"] not in COLUMN_FAMILY for c in head_cols):
        header["minor"] = MINOR
        ident = _check_identities(program, [_segment_dict(sg) for sg in segments], int(n or 0))
        header.update(ident)
    return json.dumps(header, separators=(",", ":")).encode() + b"\n" + b"".join(parts)


class SegmentWire(TypedDict):
    """A segment as the drive header carries it (:class:`Segment`)."""

    i: int
    tool: int
    line: int
    override: NotRequired[float | None]


class Identities(TypedDict, total=False):
    """The minor-1 keys of a drive header: the program's name and the segments."""

    program: str
    segments: list[SegmentWire]


def _override(v: float | None) -> float | None:
    return None if v is None else float(v)


def _segment_dict(sg: Segment) -> SegmentWire:
    d: SegmentWire = {"i": int(sg.i), "tool": int(sg.tool), "line": int(sg.line)}
    if sg.override is not None:
        d["override"] = float(sg.override)
    return d


def _is_int(v: Any) -> bool:
    return isinstance(v, int) and not isinstance(v, bool)


def _check_identities(program: Any, segments: Any, n: int) -> Identities:
    """Check the minor-1 keys; returns them as they travel."""
    out: Identities = {}
    if program is not None:
        if not isinstance(program, str) or not 1 <= len(program) <= MAX_PROGRAM:
            raise WireError(
                "schema",
                f"drive header: program expected a name of 1-{MAX_PROGRAM} characters, "
                f"got {program!r}",
            )
        out["program"] = program
    if segments is None or segments == []:
        return out
    if not isinstance(segments, list):
        raise WireError(
            "schema", f"drive header: segments expected a list, got {type(segments).__name__}"
        )
    prev = -1
    clean: list[SegmentWire] = []
    for j, sg in enumerate(segments):
        if not isinstance(sg, dict):
            raise WireError("schema", f"drive header: segments[{j}] expected an object")
        for key in ("i", "tool", "line"):
            if not _is_int(sg.get(key)) or sg[key] < 0:
                raise WireError(
                    "schema",
                    f"drive header: segments[{j}].{key} expected an integer >= 0, "
                    f"got {sg.get(key)!r}",
                )
        i = sg["i"]
        if (j == 0 and i != 0) or (j > 0 and i <= prev) or (n > 0 and i >= n):
            raise WireError(
                "shape",
                f"drive header: segments[{j}].i expected {'0' if j == 0 else f'> {prev}'} "
                f"and < n = {n}, got {i}",
            )
        prev = i
        ov = sg.get("override")
        if ov is not None and (
            not isinstance(ov, int | float) or isinstance(ov, bool) or not 0.0 < float(ov) <= 3.0
        ):
            raise WireError(
                "value", f"drive header: segments[{j}].override expected in (0, 3], got {ov!r}"
            )
        seg: SegmentWire = {"i": i, "tool": sg["tool"], "line": sg["line"]}
        if "override" in sg:
            seg["override"] = ov
        clean.append(seg)
    out["segments"] = clean
    return out


def _field(header: Mapping[str, Any], name: str, typ: type | tuple[type, ...]) -> Any:
    if name not in header:
        raise WireError("schema", f"drive header: field {name!r} missing")
    v = header[name]
    if not isinstance(v, typ) or isinstance(v, bool):
        raise WireError(
            "schema", f"drive header: field {name!r}: expected {typ}, got {type(v).__name__}"
        )
    return v


def _read_column(
    c: Any, body: memoryview, pos: int, n: int, seen: Mapping[str, Any]
) -> tuple[str, str, F64, int]:
    """One column's name, unit, values (float64) and size in the body, read from ``body``
    at ``pos`` and checked."""
    if not isinstance(c, dict):
        raise WireError("schema", f"drive header: a column entry is {type(c).__name__}")
    name, dt, unit = c.get("name"), c.get("dtype"), c.get("unit")
    if not _name_ok(name):
        raise WireError("schema", f"column {name!r}: expected a name of 1-200 characters without ,")
    name = str(name)
    if name in seen:
        raise WireError("schema", f"column {name!r} appears twice")
    if dt not in DTYPES:
        raise WireError("schema", f"column {name!r}: dtype expected <f4 or <f8, got {dt!r}")
    if not isinstance(unit, str) or (name in COLUMN_FAMILY and not _unit_ok(name, unit)):
        raise WireError(
            "units", f"column {name!r}: unit expected one of {_expected_units(name)}, got {unit!r}"
        )
    size = n * (4 if dt == "<f4" else 8)
    if pos + size > len(body):
        raise WireError(
            "shape", f"drive block: body {len(body)} bytes, columns need more ({name!r})"
        )
    a = np.frombuffer(body[pos : pos + size], dtype=dt).astype(np.float64)
    # the columns of minor 0 keep their checks; a machine's others are checked against its
    # description (check_block), where it is known which are required
    if name in COLUMN_FAMILY and name != "f_ext" and not np.all(np.isfinite(a)):
        raise WireError("value", f"column {name!r}: non-finite samples")
    return name, unit, a, size


def decode_drive(payload: bytes) -> DriveBlock:
    """Decode and check one drive block.

    Raises
    ------
    WireError
        With ``kind`` ``schema`` (not a drive block, bad header), ``version`` (another
        schema version), ``units``, ``shape`` (body length, columns) or ``value``
        (non-finite samples, bad sample time).
    """
    if len(payload) > MAX_PAYLOAD:
        raise WireError("shape", f"drive block: {len(payload)} bytes, limit {MAX_PAYLOAD}")
    nl = payload.find(b"\n", 0, MAX_HEADER)
    if nl < 0:
        raise WireError("schema", "drive block: no JSON header line in the first 4096 bytes")
    try:
        header = json.loads(payload[:nl])
    except (UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise WireError("schema", f"drive block: header is not JSON ({exc})") from None
    if not isinstance(header, dict) or header.get("schema") != DRIVE_SCHEMA:
        got = header.get("schema") if isinstance(header, dict) else type(header).__name__
        raise WireError("schema", f"drive header: schema expected {DRIVE_SCHEMA!r}, got {got!r}")
    version = header.get("version")
    if version != VERSION:
        raise WireError("version", f"drive header: version expected {VERSION}, got {version!r}")
    seq = _field(header, "seq", int)
    t0 = float(_field(header, "t0", (int, float)))
    ts = float(_field(header, "sample_time", (int, float)))
    n = _field(header, "n", int)
    cols = _field(header, "columns", list)
    if not (math.isfinite(ts) and ts > 0) or not math.isfinite(t0):
        raise WireError("value", f"drive header: sample_time {ts!r} / t0 {t0!r} not finite > 0")
    if n < 0:
        raise WireError("shape", f"drive header: n expected >= 0, got {n}")
    body = memoryview(payload)[nl + 1 :]
    out: dict[str, F64] = {}
    units: dict[str, str] = {}
    pos = 0
    for c in cols:
        name, unit, a, size = _read_column(c, body, pos, n, out)
        pos += size
        out[name] = a
        units[name] = unit
    if pos != len(body):
        raise WireError("shape", f"drive block: body {len(body)} bytes, columns take {pos}")
    wall = header.get("wall")
    wall = float(wall) if isinstance(wall, int | float) and not isinstance(wall, bool) else None
    minor = header.get("minor", 0)
    if not _is_int(minor) or minor < 0:
        raise WireError("version", f"drive header: minor expected an integer >= 0, got {minor!r}")
    if minor < 2 and ("q_m" not in out or not ({"tau_m", "i_m"} & out.keys())):
        # before minor 2 a block was one axis: its position and effort are in every block
        raise WireError(
            "schema", f"drive block: columns {sorted(out)}: expected q_m and tau_m or i_m"
        )
    ident: Identities = (
        _check_identities(header.get("program"), header.get("segments"), n) if minor >= 1 else {}
    )
    segs = tuple(
        Segment(sg["i"], sg["tool"], sg["line"], _override(sg.get("override")))
        for sg in ident.get("segments", [])
    )
    return DriveBlock(
        seq=seq,
        t0=t0,
        sample_time=ts,
        columns=out,
        units=units,
        wall=wall,
        minor=minor,
        program=ident.get("program"),
        segments=segs,
    )


def encode_drive_json(
    seq: int, t0: float, sample_time: float, columns: Mapping[str, Any], units: Mapping[str, str]
) -> bytes:
    """The same block as plain JSON (for the size/speed comparison in ``cutwatch bench``)."""
    return json.dumps(
        {
            "schema": DRIVE_SCHEMA,
            "version": VERSION,
            "seq": seq,
            "t0": t0,
            "sample_time": sample_time,
            "units": dict(units),
            "columns": {k: np.asarray(v, dtype=np.float64).tolist() for k, v in columns.items()},
        },
        separators=(",", ":"),
    ).encode()


def decode_drive_json(payload: bytes) -> dict[str, F64]:
    d = json.loads(payload)
    return {k: np.asarray(v, dtype=np.float64) for k, v in d["columns"].items()}


@dataclass(frozen=True)
class CheckedBlock:
    """A drive block as its machine has it: ``columns`` holds every described signal's
    source (NaN for an optional one this block lacks); ``ignored`` the block's other
    columns, by name (to be counted: they never cost the block)."""

    columns: dict[str, F64]
    ignored: tuple[str, ...]


def check_block(block: DriveBlock, machine: MachineDescription) -> CheckedBlock:
    """The columns of ``block`` that ``machine`` describes, checked.

    Raises
    ------
    WireError
        ``shape``: a required signal's column is missing; ``units``: a described column
        in another unit than the description's; ``value``: a required signal with
        non-finite samples (the message names the column and its axis and role).
    """
    n = block.n
    out: dict[str, F64] = {}
    for sig in machine.signals():
        if sig.owner == "identities" and sig.source not in block.columns:
            continue  # identities travel in the header
        required = _required(machine, sig)
        what = f"column {sig.source!r} ({sig.owner}.{sig.role})"
        v = block.columns.get(sig.source)
        if v is None:
            if required:
                raise WireError("shape", f"{what}: missing; the machine description requires it")
            out[sig.source] = np.full(n, np.nan)
            continue
        got = block.units.get(sig.source, "")
        if sig.unit and got != sig.unit:
            raise WireError("units", f"{what}: unit expected {sig.unit!r} (the meta), got {got!r}")
        if required and not np.all(np.isfinite(v)):
            raise WireError("value", f"{what}: non-finite samples")
        out[sig.source] = v
    ignored = tuple(k for k in block.columns if k not in out)
    return CheckedBlock(out, ignored)


def _required(machine: MachineDescription, sig: Signal) -> bool:
    if sig.owner in ("spindle", "identities"):
        return False
    return sig.role in machine.axis(sig.owner).required_roles


def machine_of(meta: Mapping[str, Any]) -> MachineDescription:
    """The machine a (decoded) meta describes: its ``axes``, or the one axis of a minor-0
    meta (:func:`common.machine_description.from_legacy`).

    Raises
    ------
    WireError
        The description breaks its schema (``units`` when the key is a unit, ``value``
        for the sample time, else ``schema``), naming the key, the expected and the found.
    """
    try:
        return describe(meta)
    except DescriptionError as exc:
        key = exc.name
        kind = "units" if "units" in key else "value" if key == "sample_time" else "schema"
        raise WireError(kind, f"meta: {exc}") from None


def _legacy_keys(machine: MachineDescription) -> dict[str, Any]:
    """The minor-0 keys of a one-axis machine whose columns have the old names, so an
    older receiver still reads the meta; {} for any other machine."""
    if len(machine.axes) != 1:
        return {}
    ax = machine.axes[0]
    if any(src != role for role, src in ax.signals.items()):
        return {}
    current = "i_m" in ax.signals and "tau_m" not in ax.signals
    nominal = dict(ax.nominal)
    if ax.K_t is not None:
        nominal["K_t"] = ax.K_t
    out: dict[str, Any] = {
        "units": {"effort": "A" if current else ax.effort_unit, "position": ax.position_unit},
        "kind": ax.kind,
        "nominal": nominal,
    }
    if ax.encoder_resolution is not None:
        out["encoder_resolution"] = ax.encoder_resolution
    return out


def encode_meta(sidecar: Mapping[str, Any]) -> bytes:
    """The retained ``meta`` message (minor 1): the machine the sidecar describes (its
    ``axes``, or a minor-0 sidecar's one axis), plus schema and version.

    Raises
    ------
    WireError
        The sidecar does not describe a machine (the key named).
    """
    machine = machine_of(sidecar)
    body = {
        "schema": META_SCHEMA,
        "version": VERSION,
        "minor": META_MINOR,
        **_legacy_keys(machine),
        **machine.to_dict(),
    }
    return json.dumps(body).encode()


def decode_meta(payload: bytes) -> dict[str, Any]:
    """Decode and check the ``meta`` message: minor 1 (a machine description) or minor 0
    (the sidecar's keys); see :func:`machine_of` for the machine it describes.

    Raises
    ------
    WireError
        Not JSON, another schema or version, or not a machine (the key named).
    """
    try:
        d = json.loads(payload)
    except (UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise WireError("schema", f"meta: not JSON ({exc})") from None
    if not isinstance(d, dict) or d.get("schema") != META_SCHEMA:
        raise WireError("schema", f"meta: schema expected {META_SCHEMA!r}")
    if d.get("version") != VERSION:
        raise WireError("version", f"meta: version expected {VERSION}, got {d.get('version')!r}")
    if is_legacy(d):
        _check_legacy_meta(d)
    machine_of(d)
    return d


def _check_legacy_meta(d: Mapping[str, Any]) -> None:
    ts = d.get("sample_time")
    if not isinstance(ts, int | float) or isinstance(ts, bool) or not (ts > 0):
        raise WireError("value", f"meta: sample_time expected a number > 0, got {ts!r}")
    units = d.get("units")
    if not isinstance(units, dict):
        raise WireError("schema", f"meta: units expected an object, got {units!r}")
    for fam in ("effort", "position"):
        if units.get(fam) not in UNITS[fam] | (UNITS["current"] if fam == "effort" else set()):
            raise WireError("units", f"meta: units.{fam} got {units.get(fam)!r}")


def encode_estimates(machine: str, body: Mapping[str, Any]) -> bytes:
    """The ``estimates`` message (JSON; non-finite numbers become null)."""
    from common.jsonsafe import json_safe

    return json.dumps(
        {"schema": ESTIMATES_SCHEMA, "version": VERSION, "machine": machine, **json_safe(body)},
        separators=(",", ":"),
        allow_nan=False,
    ).encode()


def decode_estimates(payload: bytes) -> dict[str, Any]:
    d = json.loads(payload)
    if not isinstance(d, dict) or d.get("schema") != ESTIMATES_SCHEMA:
        raise WireError("schema", f"estimates: schema expected {ESTIMATES_SCHEMA!r}")
    if d.get("version") != VERSION:
        raise WireError("version", f"estimates: version expected {VERSION}")
    return d
