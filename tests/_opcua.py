"""A plain OPC UA server of the tests' own (asyncua), on a free loopback port.

Not the project's ``opcua-sim``: other node names (``ns=2;s=mill/...``), its own units
(mm, A, 1/min, kW) and a rigid axis of known physics: ``q = A sin(w t)`` [mm] and a
motor current ``i = (M q'' + Fv q' + Fc sign q') / K_t`` [A], with the velocity and
acceleration the CNC exports, a spindle speed and power, a tool number. Each value is
written once per sample time with its ``SourceTimestamp`` on the sample grid (a CNC
stamps its samples); the nodes are written one by one, as a server samples them.

:func:`plain_server` runs it on its own thread and event loop; ``stop()`` stops it (a
kill, for the source: the connection drops) and ``start()`` starts it again on the same
port with the same certificate.
"""

from __future__ import annotations

import asyncio
import contextlib
import datetime as dt
import math
import threading
import time
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path

from _broker import free_port

#: the axis' physics (SI): mass [kg], viscous [N s/m], Coulomb [N], force constant [N/A]
M, FV, FC, KT = 120.0, 400.0, 30.0, 25.0
AMP_M, FREQ_HZ = 0.05, 0.25

NODES = {
    # name: (unit display, UNECE code)
    "mill/X/position": ("mm", "MMT"),
    "mill/X/velocity": ("mm/s", "2M"),
    "mill/X/acceleration": ("m/s^2", "MSK"),
    "mill/X/current": ("A", "AMP"),
    "mill/S/speed": ("1/min", "RPM"),
    "mill/S/power": ("kW", "KWT"),
    "mill/tool": ("", ""),
}

MAP = {
    "sample_time": 0.1,
    "axes": {
        "X": {
            "kind": "rigid",
            "q_m": "ns=2;s=mill/X/position",
            "qd_m": "ns=2;s=mill/X/velocity",
            "qdd_m": "ns=2;s=mill/X/acceleration",
            "i_m": "ns=2;s=mill/X/current",
            "K_t": KT,
        }
    },
    "spindle": {"speed": "ns=2;s=mill/S/speed", "power": "ns=2;s=mill/S/power"},
    "identities": {"tool": "ns=2;s=mill/tool"},
}


def values(t: float) -> dict[str, float]:
    """Every node's value at time ``t`` [s] (in the node's unit)."""
    w = 2 * math.pi * FREQ_HZ
    q, qd, qdd = (
        AMP_M * math.sin(w * t),
        AMP_M * w * math.cos(w * t),
        -AMP_M * w * w * math.sin(w * t),
    )
    force = M * qdd + FV * qd + FC * math.copysign(1.0, qd) + 200.0 * math.sin(0.7 * t)
    return {
        "mill/X/position": q * 1e3,
        "mill/X/velocity": qd * 1e3,
        "mill/X/acceleration": qdd,
        "mill/X/current": force / KT,
        "mill/S/speed": 6000.0 + 500.0 * math.sin(0.3 * t),
        "mill/S/power": 2.0 + 0.5 * math.sin(0.3 * t),
        "mill/tool": float(3 + int(t // 20) % 2),
    }


def _unece(code: str) -> int:
    v = 0
    for ch in code:
        v = (v << 8) | ord(ch)
    return v


@dataclass
class PlainServer:
    """The server (module docstring). ``secure``: Basic256Sha256 SignAndEncrypt only,
    else None only; ``sample_time`` of its writes [s]; ``certs``: where its own
    certificate is made."""

    certs: Path
    secure: bool = True
    sample_time: float = 0.1
    port: int = field(default_factory=free_port)
    writes: int = 0

    def __post_init__(self) -> None:
        self._thread: threading.Thread | None = None
        self._stop = threading.Event()
        self._ready = threading.Event()
        self.error: BaseException | None = None

    @property
    def url(self) -> str:
        return f"opc.tcp://127.0.0.1:{self.port}/plain"

    @property
    def cert(self) -> Path:
        return self.certs / "plain-server-cert.der"

    def start(self) -> None:
        self._stop.clear()
        self._ready.clear()
        self._thread = threading.Thread(target=lambda: asyncio.run(self._main()), daemon=True)
        self._thread.start()
        if not self._ready.wait(30):
            raise RuntimeError(f"the plain OPC UA server did not start: {self.error!r}")

    def stop(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(15)
            self._thread = None

    async def _main(self) -> None:
        from asyncua import Server, ua
        from asyncua.crypto.cert_gen import setup_self_signed_certificate
        from cryptography.x509.oid import ExtendedKeyUsageOID

        try:
            server = Server()
            await server.init()
            server.set_endpoint(self.url)
            server.set_server_name("plain test server")
            uri = "urn:cutwatch:tests:plain"
            await server.set_application_uri(uri)
            if self.secure:
                key = self.certs / "plain-server-key.pem"
                await setup_self_signed_certificate(
                    key, self.cert, uri, "127.0.0.1",
                    [ExtendedKeyUsageOID.CLIENT_AUTH, ExtendedKeyUsageOID.SERVER_AUTH], {},
                )  # fmt: skip
                await server.load_certificate(str(self.cert))
                await server.load_private_key(str(key))
                server.set_security_policy([ua.SecurityPolicyType.Basic256Sha256_SignAndEncrypt])
            else:
                server.set_security_policy([ua.SecurityPolicyType.NoSecurity])
            idx = await server.register_namespace("urn:cutwatch:tests:plain-nodes")
            assert idx == 2
            objs = server.nodes.objects
            nodes = {}
            for name, (disp, code) in NODES.items():
                nid = ua.NodeId(name, idx)
                var = await objs.add_variable(nid, name.rsplit("/", 1)[-1], 0.0)
                if code:
                    eu = ua.EUInformation(
                        NamespaceUri="http://www.opcfoundation.org/UA/units/un/cefact",
                        UnitId=_unece(code), DisplayName=ua.LocalizedText(disp),
                        Description=ua.LocalizedText(disp),
                    )  # fmt: skip
                    await var.add_property(0, "EngineeringUnits", eu)
                nodes[name] = var
            async with server:
                self._ready.set()
                k0 = math.ceil(time.time() / self.sample_time)
                n = 0
                while not self._stop.is_set():
                    k = k0 + n
                    n += 1
                    t_wall = k * self.sample_time
                    await asyncio.sleep(max(0.0, t_wall - time.time()))
                    stamp = dt.datetime.fromtimestamp(t_wall, dt.UTC)
                    for name, v in values(t_wall % 3600.0).items():
                        dv = ua.DataValue(
                            ua.Variant(v, ua.VariantType.Double),
                            SourceTimestamp=stamp,
                            ServerTimestamp=dt.datetime.now(dt.UTC),
                        )
                        await server.write_attribute_value(nodes[name].nodeid, dv)
                    self.writes += 1
        except BaseException as exc:
            self.error = exc
            self._ready.set()
            raise


@contextlib.contextmanager
def plain_server(certs: Path, **kw: object) -> Iterator[PlainServer]:
    """The plain server started, stopped on exit."""
    s = PlainServer(certs, **kw)  # type: ignore[arg-type]
    s.start()
    try:
        yield s
    finally:
        s.stop()
