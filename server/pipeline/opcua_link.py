"""The connection to a CNC's OPC UA server: security, the subscription, reconnects.

:class:`OpcuaLink` runs an asyncua client on its own thread and event loop. For each
connection it

1. lists the server's endpoints and picks one by :class:`OpcuaSecurity`: the strongest
   policy offered of ``Aes256_Sha256_RsaPss``, ``Aes128_Sha256_RsaOaep``,
   ``Basic256Sha256`` (the floor) in ``SignAndEncrypt`` (or the one policy named);
   ``None`` only when it is asked for by name;
2. checks the server's certificate against the trust list (certificate files, DER or PEM,
   or folders of them): an untrusted server is refused, its thumbprint (SHA-1, as OPC UA
   names certificates) named, and asked again after the backoff (a certificate put in
   the trust folder is taken then);
3. connects with the client's certificate and key (made once, self-signed, when none is
   given) and the user and password of the environment (``CUTWATCH_OPCUA_USER``,
   ``CUTWATCH_OPCUA_PASSWORD``), reads each node's ``EngineeringUnits``;
4. subscribes every node at the requested sampling interval with a queue of at least
   publishing interval / sampling interval + 1 samples, and adopts the sampling interval
   the server revised;
5. watches the session; a lost connection is the link's state (``lost: ...``), and it
   connects again after a backoff of 0.5 s doubling to 5 s.

Samples go to a thread-safe queue as ``(source, server time [s], value, overflow,
arrival wall time)``; a marker :data:`CONNECTED` is put before the first sample of each
connection. :class:`server.pipeline.opcua_source.OpcuaSource` reads them.
"""

from __future__ import annotations

import asyncio
import collections
import datetime as dt
import hashlib
import logging
import math
import os
import threading
import time
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from server.errors import CutwatchError

__all__ = [
    "CONNECTED",
    "POLICIES",
    "LinkInfo",
    "OpcuaLink",
    "OpcuaSecurity",
    "choose_endpoint",
    "engineering_units",
    "open_client",
    "thumbprint",
]

log = logging.getLogger("cutwatch.opcua")

#: the queue's marker of a new connection (the samples after it follow a gap)
CONNECTED = "__connected__"
#: the secure policies, strongest first; Basic256Sha256 is the floor
POLICIES = ("Aes256_Sha256_RsaPss", "Aes128_Sha256_RsaOaep", "Basic256Sha256")
_URI = "http://opcfoundation.org/UA/SecurityPolicy#"
#: the environment variables of the user and password
USER_ENV, PASSWORD_ENV = "CUTWATCH_OPCUA_USER", "CUTWATCH_OPCUA_PASSWORD"
#: a request's timeout, and the interval of the client's watchdog (it reads the server's
#: state; no answer within the timeout: the connection is lost) [s]. Generous: a CNC's
#: server busy with its machine (or a loaded host) answers late, and a connection
#: dropped for that loses the samples until the next one
TIMEOUT_S, WATCHDOG_S = 10.0, 5.0
#: the backoff between connection attempts [s]
BACKOFF_S = (0.5, 5.0)


@dataclass(frozen=True)
class OpcuaSecurity:
    """How to connect.

    Attributes
    ----------
    policy
        ``"best"`` (the strongest secure policy the server offers, :data:`POLICIES`), one
        of :data:`POLICIES`, or ``"None"`` (no security: only when named).
    certificate, private_key
        The client's certificate (DER or PEM) and key (PEM); None: a self-signed pair
        made once in ``cert_dir``.
    trust
        Certificate files or folders of the servers trusted. Empty with a secure policy:
        every server is refused (its thumbprint named).
    cert_dir
        Where the self-signed pair is kept.
    """

    policy: str = "best"
    certificate: Path | None = None
    private_key: Path | None = None
    trust: tuple[Path, ...] = ()
    cert_dir: Path = Path("data/opcua")

    def __post_init__(self) -> None:
        if self.policy not in ("best", "None", *POLICIES):
            raise CutwatchError(
                f"OPC UA security policy {self.policy!r}: expected best, None or one of "
                f"{', '.join(POLICIES)} (Basic256Sha256 is the floor)"
            )
        if (self.certificate is None) != (self.private_key is None):
            raise CutwatchError(
                "OPC UA client certificate and key: expected both or neither, found one"
            )


def thumbprint(der: bytes) -> str:
    """A certificate's SHA-1 thumbprint, as hex pairs (``ab:cd:...``)."""
    h = hashlib.sha1(der, usedforsecurity=False).hexdigest()
    return ":".join(h[i : i + 2] for i in range(0, len(h), 2))


def _trusted(paths: Iterable[Path]) -> set[str]:
    """The thumbprints of the certificates in ``paths`` (files or folders)."""
    from cryptography import x509
    from cryptography.hazmat.primitives.serialization import Encoding

    out: set[str] = set()
    files: list[Path] = []
    for p in paths:
        files += sorted(q for q in p.iterdir() if q.is_file()) if p.is_dir() else [p]
    for f in files:
        try:
            data = f.read_bytes()
        except OSError:
            continue
        try:
            cert = (
                x509.load_pem_x509_certificate(data)
                if b"-----BEGIN" in data
                else x509.load_der_x509_certificate(data)
            )
        except ValueError:
            continue
        out.add(thumbprint(cert.public_bytes(Encoding.DER)))
    return out


def _first_cert(der_chain: bytes) -> bytes:
    """The first certificate of a DER chain (a server may send its chain)."""
    if len(der_chain) < 4 or der_chain[0] != 0x30:
        return der_chain
    n = der_chain[1]
    if n < 0x80:
        return der_chain[: 2 + n]
    k = n & 0x7F
    length = int.from_bytes(der_chain[2 : 2 + k], "big")
    return der_chain[: 2 + k + length]


def choose_endpoint(endpoints: Sequence[Any], security: OpcuaSecurity) -> Any:
    """The endpoint to connect to (module docstring, 1).

    Raises
    ------
    CutwatchError
        The server offers no endpoint the security asks for: what it offers is named.
    """
    from asyncua import ua

    sae = ua.MessageSecurityMode.SignAndEncrypt
    if security.policy == "None":
        wanted = [("None", ua.MessageSecurityMode.None_)]
    elif security.policy == "best":
        wanted = [(p, sae) for p in POLICIES]
    else:
        wanted = [(security.policy, sae)]
    for pol, mode in wanted:
        for ep in endpoints:
            if ep.SecurityPolicyUri == _URI + pol and ep.SecurityMode == mode:
                return ep
    offered = sorted(
        {f"{ep.SecurityPolicyUri.rsplit('#', 1)[-1]}/{ep.SecurityMode.name}" for ep in endpoints}
    )
    asked = ", ".join(f"{p}/{m.name}" for p, m in wanted)
    raise CutwatchError(
        f"the server offers no endpoint of {asked}; it offers {', '.join(offered) or 'none'}"
    )


@dataclass
class LinkInfo:
    """What the link knows, for the source's status (read on the loop's thread)."""

    state: str = "connecting"
    policy: str = ""
    server_thumbprint: str = ""
    connects: int = 0
    attempts: int = 0
    last_error: str = ""
    revised_sampling_s: float = math.nan
    revised_publishing_s: float = math.nan
    queue_size: int = 0
    #: per source: (UnitId, display name) of its EngineeringUnits, None when it has none
    units: dict[str, tuple[int | None, str | None] | None] = field(default_factory=dict)


class OpcuaLink:
    """The client thread (module docstring).

    Parameters
    ----------
    url
        ``opc.tcp://host:port[/path]``.
    sources
        The node ids (as the map writes them) to subscribe.
    sampling_s, publishing_s
        The requested sampling and publishing intervals [s].
    security
        How to connect.
    """

    def __init__(
        self,
        url: str,
        sources: Sequence[str],
        sampling_s: float,
        publishing_s: float,
        security: OpcuaSecurity,
        backoff_max_s: float = BACKOFF_S[1],
    ) -> None:
        if not url.startswith("opc.tcp://"):
            raise CutwatchError(f"OPC UA server URL {url!r}: expected opc.tcp://host:port")
        self.url = url
        self.sources = tuple(sources)
        self.sampling_s = float(sampling_s)
        self.publishing_s = float(max(publishing_s, sampling_s))
        self.security = security
        self.backoff_max_s = float(backoff_max_s)
        self.info = LinkInfo()
        self.samples: collections.deque[tuple[str, float, Any, bool, float]] = collections.deque()
        self.unit_ready = threading.Event()
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._loop: asyncio.AbstractEventLoop | None = None

    @property
    def queue_size(self) -> int:
        """The monitored items' queue: publishing / sampling + 1 (issue 33, item 2)."""
        return math.ceil(self.publishing_s / self.sampling_s - 1e-9) + 1

    # -- thread ------------------------------------------------------------------------
    def start(self) -> None:
        if self._thread is None:
            self._thread = threading.Thread(target=self._main, name="cutwatch-opcua", daemon=True)
            self._thread.start()

    def stop(self, timeout: float = 5.0) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout)
            self._thread = None

    def _main(self) -> None:
        asyncio.run(self._run())

    async def _run(self) -> None:
        delay = BACKOFF_S[0]
        while not self._stop.is_set():
            self.info.attempts += 1
            try:
                await self._session()
                delay = BACKOFF_S[0]
            except CutwatchError as exc:  # refused: the reason is the user's to fix
                self.info.state = f"refused: {exc}"
                self.info.last_error = str(exc)
            except Exception as exc:
                why = f"{type(exc).__name__}: {exc}".rstrip(": ")
                was = self.info.state
                self.info.state = (
                    f"lost: {why}" if was.startswith("connected") else f"no connection: {why}"
                )
                self.info.last_error = why
                log.info("OPC UA %s: %s", self.url, why)
            if self._stop.is_set():
                break
            await self._sleep(delay)
            delay = min(delay * 2.0, self.backoff_max_s)

    async def _sleep(self, s: float) -> None:
        end = time.monotonic() + s
        while not self._stop.is_set() and time.monotonic() < end:
            await asyncio.sleep(min(0.05, end - time.monotonic()))

    async def _client(self) -> Any:
        return await open_client(self.url, self.security, self.info)

    async def _units(self, client: Any) -> None:
        for src in self.sources:
            try:
                eu = await engineering_units(client.get_node(src))
            except Exception:
                eu = None
            self.info.units[src] = None if eu is None else (
                int(eu.UnitId) if eu.UnitId not in (None, -1, 0) else None,
                eu.DisplayName.Text if eu.DisplayName is not None else None,
            )  # fmt: skip
        self.unit_ready.set()

    async def _session(self) -> None:
        client = await self._client()
        async with client:
            await self._units(client)
            handler = _Handler(self, {})
            sub = await client.create_subscription(self.publishing_s * 1e3, handler)
            self.info.revised_publishing_s = float(sub.parameters.RequestedPublishingInterval) / 1e3
            nodes = [client.get_node(s) for s in self.sources]
            handler.names = {n.nodeid: s for n, s in zip(nodes, self.sources)}
            capture = _Capture(sub.server)
            sub.server = capture
            try:
                self.samples.append((CONNECTED, math.nan, None, False, time.time()))
                await sub.subscribe_data_change(
                    nodes, queuesize=self.queue_size, sampling_interval=self.sampling_s * 1e3
                )
            finally:
                sub.server = capture.inner
            revised = [r.RevisedSamplingInterval for r in capture.results if r.StatusCode.is_good()]
            bad = [
                f"{s} ({r.StatusCode.name})"
                for s, r in zip(self.sources, capture.results)
                if not r.StatusCode.is_good()
            ]
            if bad:
                raise CutwatchError(f"the server refused to monitor {', '.join(bad)}")
            self.info.revised_sampling_s = max(revised) / 1e3 if revised else math.nan
            self.info.queue_size = self.queue_size
            self.info.connects += 1
            self.info.state = "connected"
            while not self._stop.is_set():
                await asyncio.sleep(0.1)
                await client.check_connection()  # raises when the session is lost
            self.info.state = "stopped"


async def open_client(url: str, security: OpcuaSecurity, info: LinkInfo | None = None) -> Any:
    """An asyncua client for ``url``, its endpoint chosen and its server checked (module
    docstring, 1-3), not connected yet (``async with`` it).

    Raises
    ------
    CutwatchError
        No endpoint of the security asked for, or an untrusted server (its thumbprint).
    """
    from asyncua import Client
    from asyncua.crypto import security_policies as sp

    info = info if info is not None else LinkInfo()
    probe = Client(url, timeout=TIMEOUT_S)
    ep = choose_endpoint(await probe.connect_and_get_server_endpoints(), security)
    client = Client(url, timeout=TIMEOUT_S, watchdog_intervall=WATCHDOG_S)
    client.application_uri = "urn:cutwatch:opcua-client"
    pol = ep.SecurityPolicyUri.rsplit("#", 1)[-1]
    info.policy = f"{pol}/{ep.SecurityMode.name}"
    if pol != "None":
        der = _first_cert(bytes(ep.ServerCertificate or b""))
        tp = thumbprint(der)
        info.server_thumbprint = tp
        if tp not in _trusted(security.trust):
            where = ", ".join(str(p) for p in security.trust) or "none given"
            raise CutwatchError(
                f"untrusted server certificate, thumbprint {tp} (not in the trust list: "
                f"{where}; put the server's certificate there to trust it)"
            )
        cert, key = security.certificate, security.private_key
        if cert is None or key is None:
            d = security.cert_dir
            d.mkdir(parents=True, exist_ok=True)
            cert, key = await client.setup_self_signed_certificate(
                d / "client-key.pem", d / "client-cert.der"
            )
        policy = getattr(sp, "SecurityPolicy" + pol.replace("_", ""))
        await client.set_security(
            policy, str(cert), str(key), server_certificate=der, mode=ep.SecurityMode
        )
    user = os.environ.get(USER_ENV)
    if user:
        client.set_user(user)
        client.set_password(os.environ.get(PASSWORD_ENV, ""))
    return client


async def engineering_units(node: Any) -> Any:
    """The ``EngineeringUnits`` (an EUInformation) of an analog item, or of the variable
    it belongs to (OPC 40502's positions carry theirs on ``PosDirect``/``PosIndirect``,
    beside ``ActPos``); None when neither has one."""
    for cand in (node, await node.get_parent()):
        if cand is None:
            continue
        for child in await cand.get_children():
            if (await child.read_browse_name()).Name == "EngineeringUnits":
                return await child.read_value()
    return None


class _Capture:
    """The subscription's service client, keeping the monitored items' results (the
    revised sampling intervals, which asyncua's subscribe does not return)."""

    def __init__(self, inner: Any) -> None:
        self.inner = inner
        self.results: list[Any] = []

    def __getattr__(self, name: str) -> Any:
        return getattr(self.inner, name)

    async def create_monitored_items(self, params: Any) -> Any:
        res = await self.inner.create_monitored_items(params)
        self.results = list(res)
        return res


def _seconds(t: dt.datetime | None) -> float:
    if t is None:
        return math.nan
    if t.tzinfo is None:
        t = t.replace(tzinfo=dt.UTC)
    return t.timestamp()


#: StatusCode bits: the info type DataValue, and its Overflow bit (OPC UA Part 4, 7.39)
_INFO_DATAVALUE, _INFO_MASK, _OVERFLOW = 0x0400, 0x0C00, 0x0080


def overflowed(status: int) -> bool:
    """True when a DataValue's status says the server's queue overflowed."""
    return (status & _INFO_MASK) == _INFO_DATAVALUE and bool(status & _OVERFLOW)


class _Handler:
    """asyncua's subscription handler: every data change to the link's queue."""

    def __init__(self, link: OpcuaLink, names: dict[Any, str]) -> None:
        self.link = link
        self.names = names

    def datachange_notification(self, node: Any, val: Any, data: Any) -> None:
        dv = data.monitored_item.Value
        ts = _seconds(dv.SourceTimestamp)
        if math.isnan(ts):
            ts = _seconds(dv.ServerTimestamp)
        status = int(dv.StatusCode.value) if dv.StatusCode is not None else 0
        name = self.names.get(node.nodeid, node.nodeid.to_string())
        self.link.samples.append((name, ts, val, overflowed(status), time.time()))

    def status_change_notification(self, status: Any) -> None:
        self.link.info.state = f"lost: subscription status {status.Status}"
