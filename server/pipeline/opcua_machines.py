"""The OPC UA machines of a worker (``cutwatch worker --opcua-machine/--opcua-machines``).

Each machine is a name, its server's URL, its node map and its security: on the command
line ``NAME=URL,nodes=MAP[,security=POLICY][,trust=CERT]...[,cert=PEM,key=PEM]
[,publishing=S]`` (``trust`` repeatable), or in a JSON file::

    {"machines": {"cnc-7": {"url": "opc.tcp://cnc-7:4840", "nodes": "cnc-7.json",
                            "security": "best", "trust": ["cnc-7.der"]}}}

(paths relative to the file). What a machine leaves out comes from the worker's own
``--opcua-*`` options. A bad entry is refused naming the machine and the key.
"""

from __future__ import annotations

import dataclasses
import json
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from server.errors import CutwatchError
from server.pipeline.broker import check_machine
from server.pipeline.opcua_link import OpcuaSecurity
from server.pipeline.opcua_source import OpcuaOptions, OpcuaSource
from server.records.opcua_map import load_node_map

__all__ = ["KEYS", "OpcuaMachine", "load_opcua_machines", "parse_opcua_machine"]

#: the keys of a machine's entry
KEYS = ("url", "nodes", "security", "trust", "cert", "key", "publishing")


@dataclass(frozen=True)
class OpcuaMachine:
    """One OPC UA machine of a worker: its name, node map file and connection."""

    name: str
    nodes: Path
    options: OpcuaOptions

    def source(self) -> OpcuaSource:
        """A new source of the machine (its node map read now)."""
        return OpcuaSource(load_node_map(self.nodes), self.options)


def _machine(
    name: str, entry: dict[str, Any], defaults: OpcuaSecurity, base: Path, where: str
) -> OpcuaMachine:
    try:
        check_machine(name)
    except CutwatchError as exc:
        raise CutwatchError(f"{where}: {exc}") from None
    unknown = sorted(set(entry) - set(KEYS))
    if unknown:
        raise CutwatchError(
            f"{where}.{unknown[0]}: expected one of the keys {', '.join(KEYS)}, got {unknown[0]!r}"
        )
    url = entry.get("url")
    if not isinstance(url, str) or not url.startswith("opc.tcp://") or len(url) <= 10:
        raise CutwatchError(f"{where}.url: expected opc.tcp://host:port[/path], got {url!r}")
    nodes = entry.get("nodes")
    if not isinstance(nodes, str) or not nodes:
        raise CutwatchError(f"{where}.nodes: expected a node map file, got {nodes!r}")

    def path(key: str, v: object) -> Path:
        if not isinstance(v, str) or not v:
            raise CutwatchError(f"{where}.{key}: expected a file path, got {v!r}")
        p = Path(v)
        return p if p.is_absolute() else base / p

    nodes_path = path("nodes", nodes)
    if not nodes_path.is_file():
        raise CutwatchError(f"{where}.nodes: expected a node map file, got {str(nodes_path)!r} "
                            "(no such file)")  # fmt: skip
    sec = defaults
    if "security" in entry:
        pol = entry["security"]
        if not isinstance(pol, str):
            raise CutwatchError(f"{where}.security: expected a policy name, got {pol!r}")
        try:
            sec = dataclasses.replace(sec, policy=pol)
        except CutwatchError as exc:
            raise CutwatchError(f"{where}.security: {exc}") from None
    if "trust" in entry:
        t = entry["trust"]
        items = t if isinstance(t, list) else [t]
        sec = dataclasses.replace(sec, trust=tuple(path("trust", x) for x in items))
    if ("cert" in entry) != ("key" in entry):
        raise CutwatchError(f"{where}.cert/key: expected both or neither, got "
                            f"{'cert' if 'cert' in entry else 'key'} only")  # fmt: skip
    if "cert" in entry:
        sec = dataclasses.replace(
            sec, certificate=path("cert", entry["cert"]), private_key=path("key", entry["key"])
        )
    pub: float | None = None
    if "publishing" in entry:
        v = entry["publishing"]
        try:
            pub = float(v)
        except (TypeError, ValueError):
            pub = math.nan
        if not (0.01 <= pub <= 10.0):
            raise CutwatchError(f"{where}.publishing: expected 0.01-10 s, got {v!r}")
    return OpcuaMachine(name, nodes_path, OpcuaOptions(url, pub, security=sec))


def parse_opcua_machine(spec: str, defaults: OpcuaSecurity, base: Path = Path()) -> OpcuaMachine:
    """One ``--opcua-machine NAME=URL,nodes=MAP,...`` (module docstring)."""
    where = "--opcua-machine"
    head, _, rest = spec.partition(",")
    name, eq, url = head.partition("=")
    if not eq:
        raise CutwatchError(f"{where}: expected NAME=opc.tcp://host:port,nodes=MAP, got {spec!r}")
    entry: dict[str, Any] = {"url": url.strip()}
    for item in filter(None, (s.strip() for s in rest.split(","))):
        k, eq, v = item.partition("=")
        if not eq:
            raise CutwatchError(f"{where} {name}: expected KEY=VALUE, got {item!r}")
        k = k.strip()
        if k == "trust":
            entry.setdefault("trust", []).append(v.strip())
        elif k in entry:
            raise CutwatchError(f"{where} {name}.{k}: expected once, got it twice")
        else:
            entry[k] = v.strip()
    return _machine(name.strip(), entry, defaults, base, f"{where} {name.strip()}")


def load_opcua_machines(path: Path, defaults: OpcuaSecurity) -> list[OpcuaMachine]:
    """The machines of the JSON file ``path`` (module docstring)."""
    try:
        d = json.loads(path.read_text(encoding="utf-8"))
    except OSError as exc:
        raise CutwatchError(f"--opcua-machines {path}: cannot read it ({exc.strerror})") from None
    except json.JSONDecodeError as exc:
        raise CutwatchError(f"--opcua-machines {path}: not JSON ({exc})") from None
    ms = d.get("machines") if isinstance(d, dict) else None
    if not isinstance(ms, dict) or not ms:
        want = '{"machines": {NAME: {"url": ..., "nodes": ...}}}'
        raise CutwatchError(f"--opcua-machines {path}: expected {want}, got {type(ms).__name__}")
    out = []
    for name, entry in ms.items():
        where = f"{path}: machines.{name}"
        if not isinstance(entry, dict):
            raise CutwatchError(f"{where}: expected an object, got {type(entry).__name__}")
        out.append(_machine(str(name), entry, defaults, path.parent, where))
    return out
