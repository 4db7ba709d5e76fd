"""A machine described by what its CNC hands out: axes, a spindle, identities, one rate.

The description is defined once, as the JSON Schema ``common/machine.schema.json``; this
module loads that file, validates a description against it (jsonschema, Draft 2020-12)
and turns it into frozen dataclasses. The role names (``q_m``, ``i_m``, ...; ``speed``,
``power``, ...; ``tool``, ``line``, ...) and the kinds are read from the schema, not
written a second time here.

It lives in ``common/`` because every layer needs it: the simulated machine describes
its own export with it (``machine/``), the estimators are designed from its rate, and the
server's wire format, logs, sources and API carry it (``server/``) — and ``machine`` and
``estimators`` may import nothing of ``server``.

A description that breaks the schema raises :class:`DescriptionError` naming the key
(``axes.X.units.position``), what was expected and what was found. Older carriers (a
broker meta of minor 0, a log sidecar without ``axes``: one axis given by ``kind``,
``units``, ``nominal`` and the column names ``q_m``, ``tau_m``/``i_m``, ``q_l``,
``f_ext``) are read by :func:`from_legacy` as a one-axis machine named ``axis``.
"""

from __future__ import annotations

import json
import math
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field
from functools import cache
from pathlib import Path
from typing import Any, NotRequired, TypedDict, cast

from common.errors import ParameterError

SCHEMA_PATH = Path(__file__).with_name("machine.schema.json")
#: the schema as a dict (read once, at import: the module's constants come from it)
SCHEMA: dict[str, Any] = json.loads(SCHEMA_PATH.read_text(encoding="utf-8"))
_DEFS: dict[str, Any] = SCHEMA["$defs"]

#: the axis kinds, the roles of an axis' signals, of the spindle's, and the identities
KINDS: tuple[str, ...] = tuple(_DEFS["axis"]["properties"]["kind"]["enum"])
AXIS_ROLES: tuple[str, ...] = tuple(_DEFS["axis_signals"]["properties"])
SPINDLE_ROLES: tuple[str, ...] = tuple(_DEFS["spindle"]["properties"]["signals"]["properties"])
IDENTITIES: tuple[str, ...] = tuple(_DEFS["identities"]["properties"])
#: the sample-time range [s] (10 kHz to 10 Hz)
MIN_SAMPLE_TIME: float = float(SCHEMA["properties"]["sample_time"]["minimum"])
MAX_SAMPLE_TIME: float = float(SCHEMA["properties"]["sample_time"]["maximum"])
#: the roles every sample of a block must carry finite (the others may be NaN or absent)
POSITION_ROLES = ("q_m", "q_l", "q_cmd")
#: a spindle signal's unit when the description names none
SPINDLE_DEFAULT_UNITS: dict[str, str] = {
    "speed": "rpm",
    "speed_cmd": "rpm",
    "current": "A",
    "power": "W",
    "torque": "N m",
    "load": "%",
}
#: the name of the one axis of a legacy (single-axis) carrier
LEGACY_AXIS = "axis"
#: legacy effort spellings of the log format and what they mean now
_LEGACY_EFFORT = {"N": "N", "N m": "N m", "Nm": "N m", "N*m": "N m", "A": "A"}


class Plain(str):
    """A found value that is a description in words (shown without quotes)."""


MISSING = Plain("missing")


class DescriptionError(ParameterError):
    """A machine description breaks its schema: ``name`` is the key (dotted path)."""

    def __init__(self, key: str, expected: str, found: Any) -> None:
        super().__init__(key, expected, found)
        shown = str(found) if isinstance(found, Plain) else _short(found)
        self.args = (f"machine description: key {key!r}: expected {expected}, found {shown}",)


def _short(v: Any) -> str:
    text = repr(v)
    return text if len(text) <= 80 else text[:77] + "..."


class AxisUnitsDict(TypedDict):
    """An axis' units as the description writes them (:meth:`AxisDescription.to_dict`
    always writes ``effort``; a description read may leave it out: ``N`` or ``N m``)."""

    position: str
    effort: NotRequired[str]


class AxisDict(TypedDict):
    """An axis as the description (JSON) writes it (:meth:`AxisDescription.to_dict`)."""

    kind: str
    signals: dict[str, str]
    units: AxisUnitsDict
    K_t: NotRequired[float]
    nominal: NotRequired[dict[str, float]]
    encoder_resolution: NotRequired[float]


class SpindleDict(TypedDict):
    """The spindle as the description writes it (:meth:`SpindleDescription.to_dict`
    always writes ``units``; a description read may leave them out: the defaults)."""

    signals: dict[str, str]
    units: NotRequired[dict[str, str]]


class MachineDict(TypedDict):
    """A machine as the description writes it (:meth:`MachineDescription.to_dict`; its
    schema: ``common/machine.schema.json``): what :func:`validate` lets through."""

    sample_time: float
    axes: dict[str, AxisDict]
    spindle: NotRequired[SpindleDict]
    identities: NotRequired[dict[str, str]]


@dataclass(frozen=True)
class Signal:
    """One signal of a machine: who has it (an axis name, ``spindle``, ``identities``),
    its role, its source (a column or node name) and its unit (``""`` for identities)."""

    owner: str
    role: str
    source: str
    unit: str


@dataclass(frozen=True)
class AxisDescription:
    """One feed axis: ``kind``, ``signals`` (role -> source), units, optional K_t and
    nominal (a prior)."""

    name: str
    kind: str
    signals: dict[str, str]
    position_unit: str
    effort_unit: str
    K_t: float | None = None
    nominal: dict[str, float] = field(default_factory=dict)
    encoder_resolution: float | None = None

    def has(self, role: str) -> bool:
        return role in self.signals

    @property
    def linear(self) -> bool:
        """True for a linear axis (position in m)."""
        return self.position_unit == "m"

    @property
    def required_roles(self) -> tuple[str, ...]:
        """Roles every block must carry, finite: the motor position, the effort, and the
        load position of a two-inertia axis."""
        out = ["q_m", *(r for r in ("tau_m", "i_m") if r in self.signals)]
        if self.kind == "two_inertia":
            out.append("q_l")
        return tuple(out)

    def unit(self, role: str) -> str:
        """The unit of one role's values."""
        p = self.position_unit
        if role in POSITION_ROLES:
            return p
        if role.startswith("qdd"):
            return f"{p}/s^2"
        if role.startswith("qd"):
            return f"{p}/s"
        if role == "i_m":
            return "A"
        return self.effort_unit

    def to_dict(self) -> AxisDict:
        d: AxisDict = {
            "kind": self.kind,
            "signals": dict(self.signals),
            "units": {"position": self.position_unit, "effort": self.effort_unit},
        }
        if self.K_t is not None:
            d["K_t"] = self.K_t
        if self.nominal:
            d["nominal"] = dict(self.nominal)
        if self.encoder_resolution is not None:
            d["encoder_resolution"] = self.encoder_resolution
        return d


@dataclass(frozen=True)
class SpindleDescription:
    """The spindle: ``signals`` (role -> source; ``speed`` always) and their units."""

    signals: dict[str, str]
    units: dict[str, str]

    def unit(self, role: str) -> str:
        return self.units.get(role, SPINDLE_DEFAULT_UNITS[role])

    def to_dict(self) -> SpindleDict:
        units = {r: self.unit(r) for r in self.signals if not r.endswith("_cmd")}
        return {"signals": dict(self.signals), "units": units}


@dataclass(frozen=True)
class MachineDescription:
    """A machine: ``sample_time`` [s], its axes in order, a spindle (or None) and where
    the identities come from (identity -> source)."""

    sample_time: float
    axes: tuple[AxisDescription, ...]
    spindle: SpindleDescription | None = None
    identities: dict[str, str] = field(default_factory=dict)

    @property
    def rate_hz(self) -> float:
        return 1.0 / self.sample_time

    @property
    def axis_names(self) -> tuple[str, ...]:
        return tuple(a.name for a in self.axes)

    def axis(self, name: str) -> AxisDescription:
        """The axis called ``name``.

        Raises
        ------
        DescriptionError
            No such axis (the known ones named).
        """
        for a in self.axes:
            if a.name == name:
                return a
        raise DescriptionError("axes", f"an axis of {list(self.axis_names)}", name)

    def signals(self) -> list[Signal]:
        """Every signal with its source and unit: axes in order, the spindle, then the
        identities."""
        out = [Signal(a.name, r, s, a.unit(r)) for a in self.axes for r, s in a.signals.items()]
        if self.spindle is not None:
            sp = self.spindle
            out += [Signal("spindle", r, s, sp.unit(r)) for r, s in sp.signals.items()]
        out += [Signal("identities", r, s, "") for r, s in self.identities.items()]
        return out

    def sources(self) -> dict[str, Signal]:
        """Each source name and the signal it carries."""
        return {s.source: s for s in self.signals()}

    def with_sample_time(self, sample_time: float) -> MachineDescription:
        """The same machine at another rate (checked against the schema's range)."""
        d = self.to_dict()
        d["sample_time"] = float(sample_time)
        return from_dict(d)

    def to_dict(self) -> MachineDict:
        """The description as JSON (every unit written out)."""
        d: MachineDict = {
            "sample_time": self.sample_time,
            "axes": {a.name: a.to_dict() for a in self.axes},
        }
        if self.spindle is not None:
            d["spindle"] = self.spindle.to_dict()
        if self.identities:
            d["identities"] = dict(self.identities)
        return d


# -- validation ---------------------------------------------------------------------------


@cache
def _validator() -> Any:
    import jsonschema

    jsonschema.Draft202012Validator.check_schema(SCHEMA)
    return jsonschema.Draft202012Validator(SCHEMA)


def _key(path: Iterable[Any], extra: str | None = None) -> str:
    parts = [str(p) for p in path]
    if extra is not None:
        parts.append(extra)
    return ".".join(parts) or "(top level)"


def _expected(err: Any) -> tuple[str, str | None, Any]:
    """(expected, the key below the error's path or None, found) of one schema error."""
    v, val, inst, sch = err.validator, err.validator_value, err.instance, err.schema
    # the schema's own words for a rule, by keyword ("x-expected": {"anyOf": "..."})
    hint = (sch.get("x-expected") or {}).get(v) if isinstance(sch, dict) else None
    if v == "required":
        missing = next(k for k in val if not (isinstance(inst, dict) and k in inst))
        known = sch.get("properties", {})
        unknown = [k for k in inst if known and k not in known] if isinstance(inst, dict) else []
        found = (
            MISSING if not unknown else Plain(f"missing (beside it the unknown key {unknown[0]!r})")
        )
        return hint or "a required key", missing, found
    if v == "additionalProperties" and isinstance(inst, dict):
        known = sorted(sch.get("properties", {}))
        extra = next(k for k in inst if k not in known)
        return f"one of the keys {known}", extra, Plain(f"unknown key {extra!r}")
    if v == "anyOf":
        return hint or "one of the alternatives of the schema", None, sorted(inst)
    if v == "propertyNames":
        return "names matching the schema's pattern", None, sorted(inst)
    texts = {
        "type": lambda: f"a JSON {val}",
        "enum": lambda: f"one of {val}",
        "const": lambda: repr(val),
        "minimum": lambda: f"a value >= {val}",
        "maximum": lambda: f"a value <= {val}",
        "exclusiveMinimum": lambda: f"a value > {val}",
        "minProperties": lambda: f"at least {val} entries",
        "maxProperties": lambda: f"at most {val} entries",
        "minLength": lambda: f"at least {val} characters",
        "maxLength": lambda: f"at most {val} characters",
        "pattern": lambda: f"text matching {val}",
    }
    text = texts.get(v)
    return (text() if text else err.message), None, inst


def _name_error(d: Mapping[str, Any]) -> DescriptionError | None:
    """A bad axis or nominal name, which jsonschema reports without the name's place."""
    axes = d.get("axes")
    if not isinstance(axes, dict):
        return None
    import re

    for name, ax in axes.items():
        if not re.fullmatch(_DEFS["axis_name"]["pattern"], str(name)):
            return DescriptionError(
                f"axes.{name}", "an axis name: a letter, then up to 15 letters, digits or _", name
            )
        nominal = ax.get("nominal") if isinstance(ax, dict) else None
        for k in nominal if isinstance(nominal, dict) else {}:
            if not re.fullmatch(r"[A-Za-z][A-Za-z0-9_]{0,31}", str(k)):
                return DescriptionError(f"axes.{name}.nominal", "parameter names", k)
    return None


def validate(d: Any) -> None:
    """Check ``d`` against the schema and the rules a schema cannot say.

    Raises
    ------
    DescriptionError
        Naming the first broken key (the most specific error), the expected and the found.
    """
    if not isinstance(d, Mapping):
        raise DescriptionError("(top level)", "a JSON object", type(d).__name__)
    bad_name = _name_error(d)
    if bad_name is not None:
        raise bad_name
    import jsonschema

    errors = list(_validator().iter_errors(_at_bounds(d)))
    if errors:
        err = jsonschema.exceptions.best_match(errors)
        expected, below, found = _expected(err)
        raise DescriptionError(_key(err.absolute_path, below), expected, found)
    # the schema's check above is what makes ``d`` a MachineDict
    _check_numbers(cast(MachineDict, d))
    _check_sources(cast(MachineDict, d))


def _at_bounds(d: Mapping[str, Any]) -> dict[str, Any]:
    """``d`` for the schema's check, a sample time within 1e-9 of a bound read as the
    bound (10 Hz measured from a time column is 0.10000000000000142 s); the description
    keeps its value."""
    out = dict(d)
    ts = out.get("sample_time")
    if isinstance(ts, float) and math.isfinite(ts):
        for bound in (MIN_SAMPLE_TIME, MAX_SAMPLE_TIME):
            if abs(ts - bound) <= 1e-9 * bound:
                out["sample_time"] = bound
    return out


def _check_numbers(d: MachineDict) -> None:
    """Numbers are finite (JSON readers accept NaN and Infinity; the schema cannot see)."""
    if not math.isfinite(d["sample_time"]):
        raise DescriptionError("sample_time", "a finite number of seconds", d["sample_time"])
    for name, ax in d["axes"].items():
        for k in ("K_t", "encoder_resolution"):
            if k in ax and not math.isfinite(ax[k]):
                raise DescriptionError(f"axes.{name}.{k}", "a finite number > 0", ax[k])
        for k, v in ax.get("nominal", {}).items():
            if not math.isfinite(v):
                raise DescriptionError(f"axes.{name}.nominal.{k}", "a finite number", v)


def _check_sources(d: MachineDict) -> None:
    """Each source carries one signal (two signals from one column is a slip of the pen)."""
    seen: dict[str, str] = {}
    places = [
        (f"axes.{n}.signals", ax["signals"]) for n, ax in d["axes"].items()
    ]  # fmt: skip
    if "spindle" in d:
        places.append(("spindle.signals", d["spindle"]["signals"]))
    if "identities" in d:
        places.append(("identities", d["identities"]))
    for where, sigs in places:
        for role, src in sigs.items():
            key = f"{where}.{role}"
            if src in seen:
                raise DescriptionError(
                    key, f"a source no other signal uses ({seen[src]} reads it)", src
                )
            seen[src] = key


# -- construction ----------------------------------------------------------------------


def from_dict(d: Any) -> MachineDescription:
    """A description from its JSON form (extra top-level keys are the carrier's, ignored).

    Raises
    ------
    DescriptionError
        ``d`` breaks the schema.
    """
    validate(d)
    m: MachineDict = d  # valid: :func:`validate` raised otherwise
    axes = tuple(_axis(name, ax) for name, ax in m["axes"].items())
    spindle = None
    if "spindle" in m:
        sp = m["spindle"]
        given = sp.get("units", {})
        # the commanded speed is in the speed's unit
        units = {
            r: given.get(r.removesuffix("_cmd"), SPINDLE_DEFAULT_UNITS[r]) for r in sp["signals"]
        }
        spindle = SpindleDescription(dict(sp["signals"]), units)
    return MachineDescription(
        sample_time=float(m["sample_time"]),
        axes=axes,
        spindle=spindle,
        identities=dict(m.get("identities", {})),
    )


def _axis(name: str, ax: AxisDict) -> AxisDescription:
    units = ax["units"]
    pos = units["position"]
    return AxisDescription(
        name=name,
        kind=ax["kind"],
        signals=dict(ax["signals"]),
        position_unit=pos,
        effort_unit=units.get("effort", "N" if pos == "m" else "N m"),
        K_t=None if "K_t" not in ax else float(ax["K_t"]),
        nominal={k: float(v) for k, v in ax.get("nominal", {}).items()},
        encoder_resolution=(
            None if "encoder_resolution" not in ax else float(ax["encoder_resolution"])
        ),
    )


def is_legacy(d: Mapping[str, Any]) -> bool:
    """True for a carrier without ``axes`` (a minor-0 meta, an older log sidecar)."""
    return "axes" not in d


def from_legacy(d: Mapping[str, Any], columns: Iterable[str] | None = None) -> MachineDescription:
    """The one-axis machine of an older carrier (see the module docstring).

    Parameters
    ----------
    d : mapping
        ``sample_time``, ``units`` (``effort`` N, N m or A; ``position`` m or rad),
        optional ``kind``, ``nominal`` (its ``K_t`` becomes the axis' K_t),
        ``encoder_resolution``.
    columns : iterable of str, optional
        The columns the carrier has (a log's); None: what an older publisher may send
        (``q_m``, the effort, ``q_l`` for a two-inertia kind, ``f_ext``).

    Raises
    ------
    DescriptionError
        A key missing or of the wrong kind, named as in the legacy carrier.
    """
    units = d.get("units")
    if not isinstance(units, Mapping):
        raise DescriptionError("units", 'an object {"effort": ..., "position": ...}', units)
    effort = _LEGACY_EFFORT.get(units.get("effort"))  # type: ignore[arg-type]
    if effort is None:
        raise DescriptionError(
            "units.effort", f"one of {sorted(_LEGACY_EFFORT)}", units.get("effort")
        )
    pos = units.get("position")
    if pos not in ("m", "rad"):
        raise DescriptionError("units.position", "one of ['m', 'rad']", pos)
    cols = set(columns) if columns is not None else None
    kind = d.get("kind")
    if kind is not None and kind not in KINDS:
        raise DescriptionError("kind", f"one of {list(KINDS)}", kind)
    if kind is None:
        kind = "two_inertia" if cols is not None and "q_l" in cols else "rigid"
    signals = _legacy_signals(effort, kind, cols)
    nominal = dict(d.get("nominal") or {})
    ax: AxisDict = {"kind": kind, "signals": signals, "units": {"position": pos}}
    if effort != "A":
        ax["units"]["effort"] = effort
    if "K_t" in nominal:
        ax["K_t"] = nominal["K_t"]
    if nominal:
        ax["nominal"] = nominal
    if d.get("encoder_resolution") is not None:
        ax["encoder_resolution"] = d["encoder_resolution"]
    out: dict[str, Any] = {"sample_time": d.get("sample_time"), "axes": {LEGACY_AXIS: ax}}
    ident = {k: k for k in ("tool", "line", "override") if cols is not None and k in cols}
    if ident:
        out["identities"] = ident
    return from_dict(out)


def _legacy_signals(effort: str, kind: Any, cols: set[str] | None) -> dict[str, str]:
    if effort == "A":  # a current: the i_m column, or an older log's tau_m in A
        eff = "i_m" if cols is None or "i_m" in cols or "tau_m" not in cols else "tau_m"
        signals = {"q_m": "q_m", "i_m": eff}
    else:
        signals = {"q_m": "q_m", "tau_m": "tau_m"}
    optional = ["q_l", "f_ext", "qd_m", "qdd_m"]
    for role in optional:
        wanted = (
            role in cols
            if cols is not None
            else role == "f_ext" or (role == "q_l" and kind == "two_inertia")
        )
        if wanted:
            signals[role] = role
    return signals


def describe(d: Mapping[str, Any], columns: Iterable[str] | None = None) -> MachineDescription:
    """The machine of a carrier: its ``axes`` when it has them, else :func:`from_legacy`."""
    if not isinstance(d, Mapping):
        raise DescriptionError("(top level)", "a JSON object", type(d).__name__)
    return from_legacy(d, columns) if is_legacy(d) else from_dict(d)
