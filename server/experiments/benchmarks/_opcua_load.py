"""A load server for ``cutwatch bench opcua``: ``--axes`` axes of six signals each and a
spindle, every node written once per ``--sample-time`` with its source timestamp.

Run as ``python -m server.experiments.benchmarks._opcua_load --port P --axes A
--sample-time T --cert-dir D``; it prints ``ready`` once it serves (Basic256Sha256 and
the Aes profiles, SignAndEncrypt, its certificate ``D/server-cert.der``). Node ids
``ns=2;s=A<k>.<role>`` (roles ``q_m``, ``q_cmd``, ``qd_m``, ``qdd_m``, ``i_m``,
``tau_m``: a rigid axis moving as a sinusoid, SI units) and ``ns=2;s=S.speed``, whose
value is its own source timestamp modulo 1000 s (the latency probe: a dashboard that
shows it at wall time ``w`` shows a change ``(w - value) mod 1000`` s old), and
``ns=2;s=S.power``. :func:`node_map` is the matching node map.
"""

from __future__ import annotations

import argparse
import asyncio
import datetime as dt
import importlib
import math
import time
from pathlib import Path
from typing import TYPE_CHECKING, Any

from common.state_io import JsonNode

if TYPE_CHECKING:
    from asyncua import Node

ROLES = ("q_m", "q_cmd", "qd_m", "qdd_m", "i_m", "tau_m")
URI = "urn:cutwatch:bench:opcua-load"


def node_map(axes: int, sample_time: float) -> dict[str, JsonNode]:
    """The node map of the load server."""
    return {
        "sample_time": sample_time,
        "axes": {
            f"A{k}": {
                "kind": "rigid",
                "units": {"position": "m", "effort": "N"},
                "signals": {r: f"ns=2;s=A{k}.{r}" for r in ROLES},
            }
            for k in range(axes)
        },
        "spindle": {"signals": {"speed": "ns=2;s=S.speed", "power": "ns=2;s=S.power"}},
    }


def _values(k: int, t: float) -> dict[str, float]:
    w = 2 * math.pi * (0.2 + 0.01 * k)
    q, qd, qdd = 0.05 * math.sin(w * t), 0.05 * w * math.cos(w * t), -0.05 * w * w * math.sin(w * t)
    f = 100.0 * qdd + 300.0 * qd + 20.0 * math.copysign(1.0, qd)
    return {"q_m": q, "q_cmd": q, "qd_m": qd, "qdd_m": qdd, "i_m": f / 20.0, "tau_m": f}


async def serve(port: int, axes: int, sample_time: float, cert_dir: Path) -> None:
    from asyncua import Server
    from asyncua.crypto.cert_gen import setup_self_signed_certificate
    from cryptography.x509.oid import ExtendedKeyUsageOID

    ua: Any = importlib.import_module("asyncua.ua")
    server = Server()
    await server.init()
    server.set_endpoint(f"opc.tcp://127.0.0.1:{port}/load")
    await server.set_application_uri(URI)
    cert_dir.mkdir(parents=True, exist_ok=True)
    cert, key = cert_dir / "server-cert.der", cert_dir / "server-key.pem"
    await setup_self_signed_certificate(
        key, cert, URI, "127.0.0.1",
        [ExtendedKeyUsageOID.CLIENT_AUTH, ExtendedKeyUsageOID.SERVER_AUTH], {},
    )  # fmt: skip
    await server.load_certificate(str(cert))
    await server.load_private_key(str(key))
    t = ua.SecurityPolicyType
    server.set_security_policy([t.Aes256Sha256RsaPss_SignAndEncrypt,
                                t.Basic256Sha256_SignAndEncrypt])  # fmt: skip
    idx = await server.register_namespace("urn:cutwatch:bench:nodes")
    nodes: dict[str, Node] = {}
    for name in [f"A{k}.{r}" for k in range(axes) for r in ROLES] + ["S.speed", "S.power"]:
        nodes[name] = await server.nodes.objects.add_variable(ua.NodeId(name, idx), name, 0.0)
    dbl = ua.VariantType.Double
    async with server:
        print("ready", flush=True)
        k = math.ceil(time.time() / sample_time)
        while True:
            await asyncio.sleep(max(0.0, k * sample_time - time.time()))
            ts = k * sample_time
            stamp = dt.datetime.fromtimestamp(ts, dt.UTC)
            vals = {f"A{a}.{r}": v for a in range(axes) for r, v in _values(a, ts).items()}
            vals["S.speed"] = ts % 1000.0
            vals["S.power"] = 1000.0 + 100.0 * math.sin(ts)
            for name, v in vals.items():
                dv = ua.DataValue(ua.Variant(v, dbl), SourceTimestamp=stamp)
                await server.write_attribute_value(nodes[name].nodeid, dv)
            k += 1
            if time.time() - k * sample_time > 5.0:  # fell behind: skip ahead, as a CNC would
                k = math.ceil(time.time() / sample_time)


def main() -> None:
    p = argparse.ArgumentParser()
    p.add_argument("--port", type=int, required=True)
    p.add_argument("--axes", type=int, default=16)
    p.add_argument("--sample-time", type=float, default=0.1)
    p.add_argument("--cert-dir", type=Path, required=True)
    a = p.parse_args()
    asyncio.run(serve(a.port, a.axes, a.sample_time, a.cert_dir))


if __name__ == "__main__":
    main()
