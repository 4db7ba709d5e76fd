"""A starter node map from a CNC's OPC UA address space (``cutwatch opcua browse``).

The address space is walked from ``Objects`` (breadth first, at most ``depth`` levels)
for the instances of the OPC 40502 types (CNC Systems): each ``CncAxisType`` is an axis
named by its browse name, each ``CncSpindleType`` the spindle, a ``CncChannelType`` the
program's identities. The signals are taken from the companion specification's browse
names (and two names a vendor commonly adds beside them):

==================  ================================  ===========================
role                node                              note
==================  ================================  ===========================
``q_m``             ``PosIndirect.ActPos``            the motor encoder
``q_l``             ``PosDirect.ActPos``              the linear scale, when it has a
                                                      value: the axis is then
                                                      ``two_inertia``
``q_cmd``           ``PosIndirect.CmdPos``
``tau_m``           ``ActTorque``                     N for a linear axis, N m rotary
``i_m``             a child named ``*Current``        vendor
``qd_m``            a child named ``*Velocity``       vendor
spindle ``speed``   ``ActSpeed`` (``CmdSpeed``)
spindle ``power``   ``ActPower``; ``torque``          ``ActTorque``; ``load``:
                                                      ``ActLoad``
identities          ``ToolId``, ``ActProgramBlock``,
                    ``ActProgramName``, ``ActOverride``
==================  ================================  ===========================

An axis is linear (``m``) unless ``IsRotational`` says otherwise (then ``rad``); the
values' own units come from each node's ``EngineeringUnits`` when the source runs. A
server without OPC 40502 types gets a map without axes and the list of its analog
variables (``"variables"``: node id, browse path, unit) to fill it from.
"""

from __future__ import annotations

from collections.abc import Iterable
from typing import TYPE_CHECKING, Any, NotRequired, TypedDict

from server.pipeline.opcua_link import OpcuaSecurity, engineering_units, open_client

if TYPE_CHECKING:
    from asyncua import Node

__all__ = ["browse_map"]

CNC_URI = "http://opcfoundation.org/UA/CNC"
_TYPES = {1004: "axis", 1005: "spindle", 1002: "channel"}


class MapAxis(TypedDict):
    """An axis of the starter map: its kind, its signals' node ids, its position unit."""

    kind: str
    signals: dict[str, str]
    units: dict[str, str]


class MapSpindle(TypedDict):
    """The spindle of the starter map: its signals' node ids."""

    signals: dict[str, str]


class MapVariable(TypedDict):
    """A variable with engineering units (a server without the CNC model's types)."""

    node: str
    path: str
    unit: str


class StarterMap(TypedDict):
    """What :func:`browse_map` gives: a node map to edit (``cutwatch opcua-map``)."""

    sample_time: float
    axes: dict[str, MapAxis]
    spindle: NotRequired[MapSpindle]
    identities: NotRequired[dict[str, str]]
    variables: NotRequired[list[MapVariable]]


async def _children(node: Node) -> dict[str, Node]:
    out: dict[str, Node] = {}
    for c in await node.get_children():
        out[(await c.read_browse_name()).Name] = c
    return out


async def _path(node: Any, *names: str) -> Any | None:
    for n in names:
        kids = await _children(node)
        if n not in kids:
            return None
        node = kids[n]
    return node


async def _has_value(node: Any | None) -> bool:
    if node is None:
        return False
    try:
        dv = await node.read_data_value(raise_on_bad_status=False)
    except Exception:
        return False
    return (
        bool(dv.StatusCode is None or dv.StatusCode.is_good())
        and dv.Value is not None
        and (dv.Value.Value is not None)
    )


def _id(node: Any) -> str:
    return str(node.nodeid.to_string())


async def _axis(node: Node) -> MapAxis:
    kids = await _children(node)
    signals: dict[str, str] = {}
    for role, path in (("q_m", ("PosIndirect", "ActPos")), ("q_cmd", ("PosIndirect", "CmdPos"))):
        n = await _path(node, *path)
        if n is not None:
            signals[role] = _id(n)
    scale = await _path(node, "PosDirect", "ActPos")
    if await _has_value(scale):
        signals["q_l"] = _id(scale)
    if "ActTorque" in kids:
        signals["tau_m"] = _id(kids["ActTorque"])
    for name, n in kids.items():
        if name.endswith("Current") and "i_m" not in signals:
            signals["i_m"] = _id(n)
        if name.endswith("Velocity") and "qd_m" not in signals:
            signals["qd_m"] = _id(n)
    rotary = False
    if "IsRotational" in kids:
        try:
            rotary = bool(await kids["IsRotational"].read_value())
        except Exception:
            rotary = False
    return {
        "kind": "two_inertia" if "q_l" in signals else "rigid",
        "signals": signals,
        "units": {"position": "rad" if rotary else "m"},
    }


async def _spindle(node: Node) -> MapSpindle:
    kids = await _children(node)
    names = {"speed": "ActSpeed", "speed_cmd": "CmdSpeed", "power": "ActPower",
             "torque": "ActTorque", "load": "ActLoad"}  # fmt: skip
    signals = {role: _id(kids[n]) for role, n in names.items() if n in kids}
    for name, n in kids.items():
        if name.endswith("Current"):
            signals["current"] = _id(n)
            break
    return {"signals": signals}


async def _channel(node: Any) -> dict[str, str]:
    kids = await _children(node)
    names = {"tool": "ToolId", "line": "ActProgramBlock", "program": "ActProgramName",
             "override": "ActOverride"}  # fmt: skip
    return {role: _id(kids[n]) for role, n in names.items() if n in kids}


async def _walk(root: Any, depth: int) -> Iterable[tuple[Any, list[str]]]:
    out: list[tuple[Any, list[str]]] = []
    level: list[tuple[Any, list[str]]] = [(root, [])]
    for _ in range(depth):
        nxt: list[tuple[Any, list[str]]] = []
        for node, path in level:
            for c in await node.get_children():
                name = (await c.read_browse_name()).Name
                if not name.startswith("<"):  # a type's placeholder, not an instance
                    nxt.append((c, [*path, name]))
        out += nxt
        level = nxt
    return out


async def browse_map(
    url: str, security: OpcuaSecurity, sample_time: float = 0.1, depth: int = 5
) -> StarterMap:
    """The starter map of the server at ``url`` (module docstring)."""
    from asyncua import ua

    client = await open_client(url, security)
    async with client:
        ns = await client.get_namespace_array()
        cnc = ns.index(CNC_URI) if CNC_URI in ns else -1
        axes: dict[str, MapAxis] = {}
        spindle: MapSpindle | None = None
        identities: dict[str, str] = {}
        variables: list[MapVariable] = []
        for node, path in await _walk(client.nodes.objects, depth):
            cls = await node.read_node_class()
            if cls == ua.NodeClass.Object and cnc >= 0:
                td = await node.read_type_definition()
                kind = _TYPES.get(td.Identifier) if td and td.NamespaceIndex == cnc else None
                if kind == "axis":
                    axes[path[-1]] = await _axis(node)
                elif kind == "spindle" and spindle is None:
                    spindle = await _spindle(node)
                elif kind == "channel" and not identities:
                    identities = await _channel(node)
            elif cls == ua.NodeClass.Variable and not axes:
                eu = await engineering_units(node) if path[-1] != "EngineeringUnits" else None
                if eu is not None:
                    variables.append({"node": _id(node), "path": "/".join(path),
                                      "unit": eu.DisplayName.Text or ""})  # fmt: skip
    out: StarterMap = {"sample_time": sample_time, "axes": axes}
    if spindle is not None and spindle["signals"].get("speed"):
        out["spindle"] = spindle
    if identities:
        out["identities"] = identities
    if not axes:
        out["variables"] = variables
    return out
