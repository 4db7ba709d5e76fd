"""The node map of a CNC's OPC UA server: which node carries which signal, and its units.

A node map is a machine description (``common/machine.schema.json``) whose sources are
OPC UA node ids (``ns=2;s=X.ActPos``, ``i=1234``, ``ns=3;g=...``). Two spellings are read:

- the description's own (per axis ``signals: {role: node}``, ``units``), and
- the issue's shorter one, roles beside ``kind`` and ``units``::

      {"sample_time": 0.1,
       "axes": {"X": {"kind": "rigid", "q_m": "ns=2;s=X.pos", "i_m": "ns=2;s=X.cur",
                      "units": {"position": "m", "effort": "A"}}},
       "spindle": {"speed": "ns=2;s=S.speed", "power": "ns=2;s=S.power"},
       "identities": {"tool": "ns=2;s=tool"}}

  (``effort: "A"`` says the effort is a current: the current ``i_m`` is always in A).

Both are checked against the description's schema, errors naming the key in the spelling
given (``axes.X.q_m``: expected ..., found ...), then each node id is parsed. The map's
``units`` say the units the pipeline works in (m or rad, N or N m, rpm, W...; optional:
an axis without ``units.position`` is linear, in m). The values' unit comes from each
node's ``EngineeringUnits`` and is converted (:func:`eu_factor`: mm to m, 1/min to rpm,
kW to W); where a node has none, or one of another kind, the map's unit is taken as the
values' own: it overrides the server's, and the source says so.

:func:`eu_factor` converts a value in an OPC UA engineering unit (an
``EUInformation``: its UNECE ``UnitId`` or, when that is unknown, its display name) to
the description's unit of the role: mm to m, deg to rad, 1/min to rpm, kW to W...
"""

from __future__ import annotations

import json
import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from common.machine_description import (
    AXIS_ROLES,
    SPINDLE_ROLES,
    DescriptionError,
    MachineDescription,
    from_dict,
)
from server.errors import CutwatchError

__all__ = [
    "NodeMap",
    "eu_factor",
    "load_node_map",
    "node_map_from_dict",
    "parse_node_id",
    "unece_id",
]


@dataclass(frozen=True)
class NodeMap:
    """A checked node map: the machine ``description`` (its sources are node ids) and the
    signals whose unit the map states (``"X.q_m"``, ``"spindle.power"``): those override
    the server's ``EngineeringUnits``."""

    description: MachineDescription
    stated_units: frozenset[str] = field(default_factory=frozenset)
    #: the axes whose position unit the map did not state (taken from the server)
    open_position: frozenset[str] = field(default_factory=frozenset)

    def signal_key(self, owner: str, role: str) -> str:
        return f"{owner}.{role}"


def parse_node_id(text: str, key: str) -> Any:
    """The asyncua NodeId of ``text``.

    Raises
    ------
    DescriptionError
        Not a node id (naming ``key``).
    """
    from asyncua import ua

    try:
        return ua.NodeId.from_string(text)
    except Exception:
        raise DescriptionError(
            key, "an OPC UA node id (ns=2;s=Name, ns=2;i=123, i=85...)", text
        ) from None


def _nested(d: Mapping[str, Any]) -> tuple[dict[str, Any], bool]:
    """The description's spelling of a map, and whether it was the short one."""
    out = dict(d)
    short = False
    axes = d.get("axes")
    if isinstance(axes, Mapping):
        new_axes: dict[str, Any] = {}
        for name, ax in axes.items():
            if isinstance(ax, Mapping) and "signals" not in ax:
                ax = dict(ax)
                sig = {r: ax.pop(r) for r in list(ax) if r in AXIS_ROLES}
                if sig:
                    short = True
                    ax["signals"] = sig
                units = ax.get("units")
                if isinstance(units, Mapping) and units.get("effort") == "A":
                    ax["units"] = {k: v for k, v in units.items() if k != "effort"}
            new_axes[name] = ax
        out["axes"] = new_axes
    sp = d.get("spindle")
    if isinstance(sp, Mapping) and "signals" not in sp:
        sp = dict(sp)
        sig = {r: sp.pop(r) for r in list(sp) if r in SPINDLE_ROLES}
        if sig:
            short = True
            sp["signals"] = sig
        out["spindle"] = sp
    return out, short


def node_map_from_dict(d: Any, where: str = "node map") -> NodeMap:
    """A node map from its JSON (either spelling, module docstring).

    Raises
    ------
    CutwatchError
        The map breaks the schema or a node id does not parse: the message names the key
        (as written in the map), the expected and the found.
    """
    if not isinstance(d, Mapping):
        raise CutwatchError(f"{where}: expected a JSON object, found {type(d).__name__}")
    nested, short = _nested(d)
    stated: set[str] = set()
    open_pos: set[str] = set()
    for name, ax in (nested.get("axes") or {}).items():
        if not isinstance(ax, dict):
            continue
        units = ax.get("units")
        if not isinstance(units, Mapping) or "position" not in units:
            open_pos.add(str(name))
            ax["units"] = {**(units if isinstance(units, Mapping) else {}), "position": "m"}
        else:
            stated |= {f"{name}.{r}" for r in ("q_m", "q_l", "q_cmd")}
            for r in ("qd_m", "qd_cmd", "qdd_m", "qdd_cmd"):
                stated.add(f"{name}.{r}")
        if isinstance(units, Mapping) and "effort" in units:
            stated |= {f"{name}.tau_m", f"{name}.f_ext"}
    sp = nested.get("spindle")
    if isinstance(sp, Mapping) and isinstance(sp.get("units"), Mapping):
        for r in sp["units"]:
            stated |= {f"spindle.{r}", f"spindle.{r}_cmd"}
    try:
        desc = from_dict(nested)
    except DescriptionError as exc:
        key = exc.name.replace(".signals.", ".") if short else exc.name
        text = str(exc.args[0]).replace(f"key {exc.name!r}", f"key {key!r}")
        raise CutwatchError(f"{where}: {text.removeprefix('machine description: ')}") from None
    for sig in desc.signals():
        sub = "" if sig.owner == "identities" or short else ".signals"
        owner = "axes." + sig.owner if sig.owner not in ("spindle", "identities") else sig.owner
        key = f"{owner}{sub}.{sig.role}"
        try:
            parse_node_id(sig.source, key)
        except DescriptionError as exc:
            text = str(exc.args[0]).removeprefix("machine description: ")
            raise CutwatchError(f"{where}: {text}") from None
    return NodeMap(desc, frozenset(stated), frozenset(open_pos))


def load_node_map(path: str | Path) -> NodeMap:
    """The node map in the JSON file ``path``.

    Raises
    ------
    CutwatchError
        No such file, not JSON, or a map that breaks the schema (the key named).
    """
    p = Path(path)
    try:
        text = p.read_text(encoding="utf-8")
    except OSError as exc:
        raise CutwatchError(f"node map {p}: cannot read it ({exc.strerror})") from None
    try:
        d = json.loads(text)
    except json.JSONDecodeError as exc:
        raise CutwatchError(
            f"node map {p}: not JSON (line {exc.lineno}, column {exc.colno}: {exc.msg})"
        ) from None
    return node_map_from_dict(d, f"node map {p}")


# -- engineering units ---------------------------------------------------------------------


def unece_id(code: str) -> int:
    """The OPC UA ``UnitId`` of a UNECE Rec. 20 common code (its characters, 8 bits each)."""
    v = 0
    for ch in code:
        v = (v << 8) | ord(ch)
    return v


#: unit -> (dimension, factor to the dimension's base unit), by UNECE code and by name
_BY_CODE: dict[str, tuple[str, float]] = {
    "MTR": ("length", 1.0),
    "MMT": ("length", 1e-3),
    "4H": ("length", 1e-6),
    "INH": ("length", 0.0254),
    "C81": ("angle", 1.0),
    "DD": ("angle", math.pi / 180.0),
    "AMP": ("current", 1.0),
    "4K": ("current", 1e-3),
    "NEW": ("force", 1.0),
    "B47": ("force", 1e3),
    "NU": ("torque", 1.0),
    "RPM": ("speed", 2.0 * math.pi / 60.0),
    "2A": ("speed", 1.0),
    "WTT": ("power", 1.0),
    "KWT": ("power", 1e3),
    "P1": ("percent", 1.0),
    "MTS": ("length/s", 1.0),
    "2M": ("length/s", 1e-3),
    "H81": ("length/s", 1e-3 / 60.0),
    "2X": ("length/s", 1.0 / 60.0),
    "E96": ("angle/s", math.pi / 180.0),
    "MSK": ("length/s^2", 1.0),
}
_UNIT_IDS = {unece_id(c): u for c, u in _BY_CODE.items()}
_BY_NAME: dict[str, tuple[str, float]] = {
    "m": _BY_CODE["MTR"],
    "mm": _BY_CODE["MMT"],
    "µm": _BY_CODE["4H"],
    "um": _BY_CODE["4H"],
    "in": _BY_CODE["INH"],
    "rad": _BY_CODE["C81"],
    "deg": _BY_CODE["DD"],
    "°": _BY_CODE["DD"],
    "a": _BY_CODE["AMP"],
    "ma": _BY_CODE["4K"],
    "n": _BY_CODE["NEW"],
    "kn": _BY_CODE["B47"],
    "n m": _BY_CODE["NU"],
    "nm": _BY_CODE["NU"],
    "n·m": _BY_CODE["NU"],
    "n*m": _BY_CODE["NU"],
    "rpm": _BY_CODE["RPM"],
    "1/min": _BY_CODE["RPM"],
    "min-1": _BY_CODE["RPM"],
    "min⁻¹": _BY_CODE["RPM"],
    "rev/min": _BY_CODE["RPM"],
    "rad/s": _BY_CODE["2A"],
    "1/s": ("speed", 2.0 * math.pi),
    "w": _BY_CODE["WTT"],
    "kw": _BY_CODE["KWT"],
    "%": _BY_CODE["P1"],
    "m/s": _BY_CODE["MTS"],
    "mm/s": _BY_CODE["2M"],
    "mm/min": _BY_CODE["H81"],
    "m/min": _BY_CODE["2X"],
    "deg/s": _BY_CODE["E96"],
    "rad/s^2": ("angle/s^2", 1.0),
    "m/s^2": _BY_CODE["MSK"],
    "m/s²": _BY_CODE["MSK"],
    "mm/s^2": ("length/s^2", 1e-3),
    "mm/s²": ("length/s^2", 1e-3),
}
#: the description's units as (dimension, factor): what a value is converted to
_TARGET: dict[str, tuple[str, float]] = {
    "m": ("length", 1.0),
    "rad": ("angle", 1.0),
    "m/s": ("length/s", 1.0),
    "rad/s": ("angle/s", 1.0),
    "m/s^2": ("length/s^2", 1.0),
    "rad/s^2": ("angle/s^2", 1.0),
    "A": ("current", 1.0),
    "N": ("force", 1.0),
    "N m": ("torque", 1.0),
    "rpm": ("speed", 2.0 * math.pi / 60.0),
    "1/s": ("speed", 2.0 * math.pi),
    "W": ("power", 1.0),
    "kW": ("power", 1e3),
    "%": ("percent", 1.0),
}
#: a speed of the spindle in rad/s is a "speed", of an axis an "angle/s"
_SPINDLE_SPEED = {"rad/s": ("speed", 1.0)}


def eu_unit(unit_id: int | None, display: str | None) -> tuple[str, float] | None:
    """(dimension, factor to its base) of an engineering unit; None when unknown."""
    if unit_id is not None and unit_id in _UNIT_IDS:
        return _UNIT_IDS[unit_id]
    if display:
        return _BY_NAME.get(display.strip().lower().replace("sec", "s"))
    return None


def eu_factor(
    unit_id: int | None, display: str | None, target: str, spindle: bool = False
) -> float | None:
    """The factor taking a value in the engineering unit (``unit_id``, ``display``) to
    ``target`` (a unit of the description); None when the server's unit is unknown.

    Raises
    ------
    CutwatchError
        The units are of different kinds (a length for an angle, mm for a current).
    """
    src = eu_unit(unit_id, display)
    if src is None:
        return None
    tgt = (_SPINDLE_SPEED.get(target) if spindle else None) or _TARGET.get(target)
    if tgt is None:
        return None
    if src[0] != tgt[0]:
        raise CutwatchError(
            f"engineering unit {display or unit_id!r} is a {src[0]}: expected a {tgt[0]} "
            f"(the description's {target})"
        )
    return src[1] / tgt[1]


def dimension(unit_id: int | None, display: str | None) -> str | None:
    """The kind of quantity of an engineering unit (``length``, ``angle``...), or None."""
    u = eu_unit(unit_id, display)
    return None if u is None else u[0]
