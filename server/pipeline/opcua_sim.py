"""The machining centre served as a CNC's OPC UA server would (``cutwatch opcua-sim``).

The OPC Foundation's CNC NodeSet (OPC 40502, ``Opc.Ua.CNC.NodeSet.xml`` of the npm
package ``node-opcua-nodesets``, installed with the dashboard's packages) is imported
(``import_xml``); the nodeset's own example instances (``Axes``, ``Spindles``,
``Channels``: objects with no parent, which asyncua refuses) are left out of the import
and every reference to them. Under ``Objects/CncInterface`` (a ``CncInterfaceType``):

- ``CncAxisList/X``, ``Y``, ``Z`` (``CncAxisType``): ``PosIndirect.ActPos`` (the motor
  encoder), ``PosIndirect.CmdPos``, ``PosDirect.ActPos`` (the linear scale: X only, a
  two-inertia axis; Y and Z are semi-closed and leave it empty), ``ActTorque`` (the drive's
  force, N), and two vendor items beside them, ``ActCurrent`` (A) and ``ActVelocity``
  (mm/min); positions in mm;
- ``CncSpindleList/S`` (``CncSpindleType``): ``ActSpeed`` and ``CmdSpeed`` (1/min),
  ``ActPower`` (W), ``ActTorque`` (N m), and ``ActCurrent`` (A);
- ``CncChannelList/Channel1`` (``CncChannelType``): ``ToolId``, ``ActProgramName``,
  ``ActProgramBlock`` (the line) and ``ActOverride`` (%).

Each analog item carries its ``EngineeringUnits`` (UNECE codes); node ids are strings in
the simulator's namespace, e.g. ``ns=3;s=X.PosIndirect.ActPos``.

Every ``sample_time`` of wall time the simulated machine (:mod:`machine.centre`, its CNC
trace at 500 Hz) advances by as much and each node is written with the trace's last
value and its ``SourceTimestamp``, as a CNC samples its values. Security: the server's
own self-signed certificate (made once in ``cert_dir``), ``Basic256Sha256`` and the Aes
profiles in ``SignAndEncrypt``, and ``None`` only when asked for.
"""

from __future__ import annotations

import asyncio
import datetime as dt
import importlib
import math
import time
import xml.etree.ElementTree as ET
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from server.errors import CutwatchError
from server.records.opcua_map import unece_id

__all__ = ["NODESET", "SimOptions", "cleaned_nodeset", "run_sim"]

#: the CNC NodeSet, from the dashboard's npm packages (web/package.json)
NODESET = (
    Path(__file__).resolve().parents[2]
    / "web" / "node_modules" / "node-opcua-nodesets" / "nodesets" / "Opc.Ua.CNC.NodeSet.xml"
)  # fmt: skip
CNC_URI = "http://opcfoundation.org/UA/CNC"
SIM_URI = "urn:cutwatch:opcua-sim"
_U = "{http://opcfoundation.org/UA/2011/03/UANodeSet.xsd}"
#: the CNC NodeSet's types (OPC 40502): interface, axis, spindle, channel
CNC_TYPES = {"interface": 1007, "axis": 1004, "spindle": 1005, "channel": 1002}
_NON_PARENT = {"HasTypeDefinition", "HasModellingRule", "HasEncoding", "HasDescription"}


@dataclass(frozen=True)
class SimOptions:
    """``host``, ``port``, ``sample_time`` [s] of the values, ``seed`` of the machine,
    ``security`` (``secure``: Basic256Sha256 and the Aes profiles, SignAndEncrypt;
    ``none``; ``both``), ``cert_dir`` (the server's certificate and key), ``nodeset``."""

    host: str = "127.0.0.1"
    port: int = 4840
    sample_time: float = 0.1
    seed: int = 0
    security: str = "secure"
    cert_dir: Path = Path("data/opcua-sim")
    nodeset: Path = field(default_factory=lambda: NODESET)

    @property
    def url(self) -> str:
        return f"opc.tcp://{self.host}:{self.port}/cutwatch"

    @property
    def certificate(self) -> Path:
        return self.cert_dir / "server-cert.der"

    def __post_init__(self) -> None:
        if self.security not in ("secure", "none", "both"):
            raise CutwatchError(
                f"opcua-sim security {self.security!r}: expected secure, none or both"
            )
        if not 0.01 <= self.sample_time <= 1.0:
            raise CutwatchError(
                f"opcua-sim sample time {self.sample_time!r} s: expected 0.01 to 1 s"
            )


def cleaned_nodeset(path: Path) -> str:
    """The NodeSet's XML without the instances that have no parent (and every reference
    to them): asyncua imports a nodeset node by node and refuses an orphan.

    Raises
    ------
    CutwatchError
        The file is missing (``make setup`` installs it) or not a NodeSet.
    """
    if not path.is_file():
        raise CutwatchError(
            f"the CNC NodeSet {path} is missing: `make setup` installs the npm package "
            "node-opcua-nodesets (web/package.json)"
        )
    ET.register_namespace("", _U[1:-1])
    try:
        root = ET.parse(path).getroot()
    except ET.ParseError as exc:
        raise CutwatchError(f"{path}: not a NodeSet ({exc})") from None
    nodes = [el for el in root if el.get("NodeId")]

    def refs(el: ET.Element) -> list[ET.Element]:
        r = el.find(_U + "References")
        return list(r) if r is not None else []

    targets = {
        r.text.strip()
        for el in nodes
        for r in refs(el)
        if r.get("IsForward") != "false" and r.get("ReferenceType") not in _NON_PARENT and r.text
    }
    drop = {
        el.get("NodeId", "")
        for el in nodes
        if el.tag.endswith(("UAObject", "UAVariable", "UAMethod"))
        and el.get("ParentNodeId") is None
        and not any(r.get("IsForward") == "false" for r in refs(el))
        and el.get("NodeId") not in targets
    }
    changed = True
    while changed:  # what hangs only from a dropped node goes too
        changed = False
        for el in nodes:
            nid = el.get("NodeId", "")
            if nid in drop:
                continue
            inv = [
                (r.text or "").strip()
                for r in refs(el)
                if r.get("IsForward") == "false" and r.get("ReferenceType") not in _NON_PARENT
            ]
            if el.get("ParentNodeId") in drop or (inv and all(i in drop for i in inv)):
                drop.add(nid)
                changed = True
    for el in nodes:
        if el.get("NodeId") in drop:
            root.remove(el)
            continue
        r = el.find(_U + "References")
        for ref in refs(el):
            if (ref.text or "").strip() in drop and r is not None:
                r.remove(ref)
    return ET.tostring(root, encoding="unicode")


@dataclass
class _Item:
    """One served node: its asyncua node, its variant type and how it is computed from
    a trace sample (columns by name, at index -1)."""

    node: Any
    vtype: Any
    value: Callable[[dict[str, float]], Any]


def _scaled(col: str, f: float) -> Callable[[dict[str, float]], float]:
    """A trace column times ``f`` (mm from m...)."""
    return lambda c: c[col] * f


def _spindle_torque(c: dict[str, float]) -> float:
    """The spindle's torque from its power and speed [N m] (0 at rest)."""
    omega = c["S_speed"] * 2.0 * math.pi / 60.0
    return float(c["S_power"] / omega) if abs(omega) > 1.0 else 0.0


async def _eu(node: Any, code: str, text: str) -> None:
    """Set (or add) the node's EngineeringUnits."""
    ua: Any = importlib.import_module("asyncua.ua")

    eu = ua.EUInformation(
        NamespaceUri="http://www.opcfoundation.org/UA/units/un/cefact",
        UnitId=unece_id(code),
        DisplayName=ua.LocalizedText(text),
        Description=ua.LocalizedText(text),
    )
    for child in await node.get_children():
        if (await child.read_browse_name()).Name == "EngineeringUnits":
            await child.write_value(ua.Variant(eu, ua.VariantType.ExtensionObject))
            return
    await node.add_property(0, "EngineeringUnits", eu)


class _Machine:
    """The machining centre and its CNC trace, advanced one sample time at a time."""

    def __init__(self, seed: int, sample_time: float) -> None:
        from machine.centre import signals
        from machine.centre.program import program_variant
        from machine.centre.sim import MachiningCentre
        from machine.centre.trace import CncTrace, TraceParams

        self.signals = signals
        self.machine = MachiningCentre(program=program_variant(0))
        self.state = self.machine.initial_state(seed=seed)
        self.trace = CncTrace(TraceParams(500.0, "sample"), self.machine.sample_time)
        self.tstate = self.trace.initial_state()
        self.per = max(1, round(sample_time * 500.0))
        self.program = self.machine.program.name
        self.params = self.machine.params

    def step(self) -> dict[str, float]:
        """The trace over the next sample time: its last values by column."""
        self.state, rec = self.machine.step(self.state, self.per * self.trace.factor)
        self.tstate, tr = self.trace.export(self.tstate, rec)
        return {
            k: float(np.asarray(v)[-1]) for k, v in self.signals.columns(tr, self.params).items()
        }


async def _address_space(server: Any, m: _Machine) -> list[_Item]:
    """The CNC interface of the machine (module docstring) and its served items."""
    ua: Any = importlib.import_module("asyncua.ua")

    cnc = await server.get_namespace_index(CNC_URI)
    idx = await server.register_namespace(SIM_URI)
    dbl, u32, txt = ua.VariantType.Double, ua.VariantType.UInt32, ua.VariantType.String
    iface = await server.nodes.objects.add_object(
        ua.NodeId("CncInterface", idx), ua.QualifiedName("CncInterface", cnc),
        objecttype=ua.NodeId(CNC_TYPES["interface"], cnc),
    )  # fmt: skip
    items: list[_Item] = []

    async def child(parent: Any, path: str) -> Any:
        node = parent
        for part in path.split("."):
            node = await node.get_child(f"{cnc}:{part}")
        return node

    async def vendor(parent: Any, name: str, code: str, unit: str) -> Any:
        pid = parent.nodeid.Identifier
        node = await parent.add_variable(
            ua.NodeId(f"{pid}.{name}", idx), ua.QualifiedName(name, idx), 0.0, varianttype=dbl
        )
        await _eu(node, code, unit)
        return node

    axes = await child(iface, "CncAxisList")
    for ax in m.params.axes:
        a = await axes.add_object(ua.NodeId(ax.name, idx), ua.QualifiedName(ax.name, cnc),
                                  objecttype=ua.NodeId(CNC_TYPES["axis"], cnc))  # fmt: skip
        n = ax.name
        for pos in ("PosIndirect", "PosDirect"):
            await _eu(await child(a, pos), "MMT", "mm")
        k_t = ax.force_constant
        spec = [
            ("PosIndirect.ActPos", f"{n}_q_m", 1e3),
            ("PosIndirect.CmdPos", f"{n}_q_cmd", 1e3),
            *([("PosDirect.ActPos", f"{n}_q_l", 1e3)] if ax.kind == "two_inertia" else []),
        ]
        for path, col, f in spec:
            items.append(_Item(await child(a, path), dbl, _scaled(col, f)))
        if ax.kind != "two_inertia":  # semi-closed: no linear scale, its value says so
            direct = await child(a, "PosDirect.ActPos")
            await server.write_attribute_value(
                direct.nodeid,
                ua.DataValue(StatusCode=ua.StatusCode(ua.StatusCodes.BadNotConnected)),
            )
        torque = await child(a, "ActTorque")
        await _eu(torque, "NEW", "N")
        items.append(_Item(torque, dbl, _scaled(f"{n}_i_m", k_t)))
        cur = await vendor(a, "ActCurrent", "AMP", "A")
        items.append(_Item(cur, dbl, _scaled(f"{n}_i_m", 1.0)))
        vel = await vendor(a, "ActVelocity", "H81", "mm/min")
        items.append(_Item(vel, dbl, _scaled(f"{n}_qd_m", 6e4)))
    spindles = await child(iface, "CncSpindleList")
    s = await spindles.add_object(ua.NodeId("S", idx), ua.QualifiedName("S", cnc),
                                  objecttype=ua.NodeId(CNC_TYPES["spindle"], cnc))  # fmt: skip
    for path, col, code, unit in (("ActSpeed", "S_speed", "RPM", "1/min"),
                                  ("CmdSpeed", "S_speed_cmd", "RPM", "1/min"),
                                  ("ActPower", "S_power", "WTT", "W")):  # fmt: skip
        node = await child(s, path)
        await _eu(node, code, unit)
        items.append(_Item(node, dbl, _scaled(col, 1.0)))
    torque = await child(s, "ActTorque")
    await _eu(torque, "NU", "N m")
    items.append(_Item(torque, dbl, _spindle_torque))
    load = await child(s, "ActLoad")
    await _eu(load, "P1", "%")
    rated = float(m.params.spindle.max_power)
    items.append(_Item(load, dbl, lambda c: 100.0 * c["S_power"] / rated))
    cur = await vendor(s, "ActCurrent", "AMP", "A")
    items.append(_Item(cur, dbl, lambda c: c["S_current"]))
    channels = await child(iface, "CncChannelList")
    ch = await channels.add_object(ua.NodeId("Channel1", idx), ua.QualifiedName("Channel1", cnc),
                                   objecttype=ua.NodeId(CNC_TYPES["channel"], cnc))  # fmt: skip
    items.append(_Item(await child(ch, "ToolId"), u32, lambda c: int(c["tool"])))
    items.append(_Item(await child(ch, "ActProgramBlock"), txt, lambda c: f"N{int(c['line'])}"))
    items.append(_Item(await child(ch, "ActOverride"), dbl, lambda c: 100.0 * c["override"]))
    prog = await child(ch, "ActProgramName")
    await prog.write_value(ua.Variant(m.program, txt))
    return items


async def _secure(server: Any, opts: SimOptions) -> None:
    ua: Any = importlib.import_module("asyncua.ua")
    from asyncua.crypto.cert_gen import setup_self_signed_certificate
    from cryptography.x509.oid import ExtendedKeyUsageOID

    t = ua.SecurityPolicyType
    secure = [t.Aes256Sha256RsaPss_SignAndEncrypt, t.Aes128Sha256RsaOaep_SignAndEncrypt,
              t.Basic256Sha256_SignAndEncrypt]  # fmt: skip
    policies = {"secure": secure, "none": [t.NoSecurity], "both": [*secure, t.NoSecurity]}
    if opts.security != "none":
        opts.cert_dir.mkdir(parents=True, exist_ok=True)
        key = opts.cert_dir / "server-key.pem"
        await setup_self_signed_certificate(
            key, opts.certificate, SIM_URI, opts.host,
            [ExtendedKeyUsageOID.CLIENT_AUTH, ExtendedKeyUsageOID.SERVER_AUTH], {},
        )  # fmt: skip
        await server.load_certificate(str(opts.certificate))
        await server.load_private_key(str(key))
    server.set_security_policy(policies[opts.security])


async def run_sim(
    opts: SimOptions, stop: asyncio.Event | None = None, ready: Callable[[], None] | None = None
) -> None:
    """Serve the machine until ``stop`` is set (or forever)."""
    from asyncua import Server

    ua: Any = importlib.import_module("asyncua.ua")

    xml = cleaned_nodeset(opts.nodeset)
    server = Server()
    await server.init()
    server.set_endpoint(opts.url)
    server.set_server_name("cutwatch machining centre (simulated CNC)")
    await server.set_application_uri(SIM_URI)
    await _secure(server, opts)
    await server.import_xml(xmlstring=xml)
    m = _Machine(opts.seed, opts.sample_time)
    items = await _address_space(server, m)
    stop = stop or asyncio.Event()
    ts = opts.sample_time
    async with server:
        if ready is not None:
            ready()
        k = math.ceil(time.time() / ts)
        while not stop.is_set():
            await asyncio.sleep(max(0.0, k * ts - time.time()))
            cols = m.step()
            stamp = dt.datetime.fromtimestamp(k * ts, dt.UTC)
            now = dt.datetime.now(dt.UTC)
            for it in items:
                dv = ua.DataValue(ua.Variant(it.value(cols), it.vtype),
                                  SourceTimestamp=stamp, ServerTimestamp=now)  # fmt: skip
                await server.write_attribute_value(it.node.nodeid, dv)
            k += 1
            if time.time() - k * ts > 5.0:  # fell behind by more than 5 s: skip ahead
                k = math.ceil(time.time() / ts)
