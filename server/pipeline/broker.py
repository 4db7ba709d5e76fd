"""The MQTT broker connection: address, credentials, TLS, topics, and the client.

The client is Eclipse paho-mqtt (2.x, callback API version 2). Why paho and not
aiomqtt: the live pipeline runs in its own thread, not on the event loop, and paho's
network thread hands messages to a thread-safe queue the loop drains at its own pace;
paho reconnects by itself with an exponential backoff (``reconnect_delay_set``), and
aiomqtt is itself a wrapper around paho for asyncio code. ``cutwatch feed`` and the
fleet page use the same client.

Topics (docs/design.md, "Broker"): ``cutwatch/<machine>/drive`` (blocks in),
``cutwatch/<machine>/meta`` (retained sidecar), ``cutwatch/<machine>/estimates``,
``cutwatch/<machine>/events`` and ``cutwatch/<machine>/command`` (out). Who may publish
what is the broker's access list (deploy/mosquitto/acl, docs/broker.md).
"""

from __future__ import annotations

import re
import ssl
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Protocol
from urllib.parse import unquote, urlsplit

from server.errors import CutwatchError

TOPIC_ROOT = "cutwatch"
_MACHINE_RE = re.compile(r"[A-Za-z0-9][A-Za-z0-9_.-]{0,63}")  # fullmatch: no final newline


def topic(machine: str, leaf: str) -> str:
    """``cutwatch/<machine>/<leaf>`` after checking the machine name."""
    check_machine(machine)
    return f"{TOPIC_ROOT}/{machine}/{leaf}"


def check_machine(machine: str) -> str:
    """A machine name is 1-64 characters of letters, digits, ``_ . -`` (no MQTT wildcards)."""
    if not _MACHINE_RE.fullmatch(machine):
        raise CutwatchError(
            f"machine name {machine!r}: expected 1-64 characters from A-Z a-z 0-9 _ . - "
            "starting with a letter or digit"
        )
    return machine


@dataclass(frozen=True)
class BrokerConfig:
    """Where and how to connect. ``url`` is ``mqtt://host[:port]`` or ``mqtts://...`` (TLS).

    With TLS the broker's certificate is verified (chain and host name) against ``cafile``,
    or the system's trusted authorities when none is given; ``certfile``/``keyfile`` are
    this client's own certificate, for a broker that requires one.
    """

    host: str
    port: int
    tls: bool = False
    username: str | None = None
    password: str | None = None
    cafile: Path | None = None
    certfile: Path | None = None
    keyfile: Path | None = None
    keepalive: int = 30

    def describe(self) -> str:
        """The address without the password (for logs and health)."""
        user = f"{self.username}@" if self.username else ""
        return f"{'mqtts' if self.tls else 'mqtt'}://{user}{self.host}:{self.port}"


def _existing(f: str | Path | None, what: str) -> Path | None:
    """``f`` as a path (None when not given), after checking that the file exists."""
    if not f:
        return None
    if not Path(f).is_file():
        raise CutwatchError(f"broker {what} {str(f)!r}: no such file")
    return Path(f)


def parse_broker_url(
    url: str,
    *,
    username: str | None = None,
    password: str | None = None,
    cafile: str | Path | None = None,
    certfile: str | Path | None = None,
    keyfile: str | Path | None = None,
) -> BrokerConfig:
    """Parse ``mqtt://[user[:password]@]host[:port]`` (or ``mqtts://``, TLS, port 8883).

    Explicit ``username``/``password`` override the URL's. A ``cafile`` or a client
    ``certfile`` implies TLS; a ``keyfile`` needs a ``certfile`` (a ``certfile`` alone
    holds its key too).

    Raises
    ------
    CutwatchError
        The URL is not of that form, a file does not exist, or a key comes without its
        certificate.
    """
    parts = urlsplit(url)
    if parts.scheme not in ("mqtt", "mqtts") or not parts.hostname:
        raise CutwatchError(
            f"broker URL {url!r}: expected mqtt://host[:port] or mqtts://host[:port]"
        )
    try:
        port = parts.port
    except ValueError:
        raise CutwatchError(f"broker URL {url!r}: port expected 1-65535") from None
    ca = _existing(cafile, "CA file")
    cert = _existing(certfile, "client certificate")
    key = _existing(keyfile, "client key")
    if key is not None and cert is None:
        raise CutwatchError(
            f"broker client key {str(key)!r}: expected a client certificate with it, got none"
        )
    tls = parts.scheme == "mqtts" or ca is not None or cert is not None
    return BrokerConfig(
        host=parts.hostname,
        port=port or (8883 if tls else 1883),
        tls=tls,
        username=username if username is not None else unquote(parts.username or "") or None,
        password=password if password is not None else unquote(parts.password or "") or None,
        cafile=ca,
        certfile=cert,
        keyfile=key,
    )


def make_client(cfg: BrokerConfig, client_id: str = "") -> object:
    """A paho client set up for ``cfg`` (not yet connected).

    Returns ``paho.mqtt.client.Client`` (typed ``object`` here so paho is imported only
    where a broker is used).

    Raises
    ------
    CutwatchError
        A CA file, client certificate or key that is not one (or a key that does not
        match its certificate), naming the file.
    """
    import paho.mqtt.client as mqtt

    c = mqtt.Client(mqtt.CallbackAPIVersion.VERSION2, client_id=client_id, protocol=mqtt.MQTTv311)
    if cfg.username:
        c.username_pw_set(cfg.username, cfg.password)
    if cfg.tls:
        c.tls_set_context(tls_context(cfg))
    c.reconnect_delay_set(min_delay=1, max_delay=30)
    return c


class LinkState(Protocol):
    """What a publisher shows of its broker connection."""

    connected: bool
    last_error: str


def connect_in_background(
    cfg: BrokerConfig, client_id: str, state: LinkState, max_queued: int = 0
) -> Any:
    """A client for ``cfg`` connecting (and reconnecting) on paho's network thread, its
    link kept on ``state.connected`` and ``state.last_error``; ``max_queued`` > 0 bounds
    the messages paho keeps while away. Returns the started ``paho`` client."""
    c: Any = make_client(cfg, client_id=client_id)
    if max_queued > 0:
        c.max_queued_messages_set(max_queued)

    def on_connect(_c: object, _u: object, _f: object, rc: Any, _p: object = None) -> None:
        failed = getattr(rc, "is_failure", False)
        state.connected = not failed
        state.last_error = f"refused: {reason_text(rc)}" if failed else ""

    def on_disconnect(_c: object, _u: object, _f: object, rc: Any, _p: object = None) -> None:
        state.connected = False

    c.on_connect = on_connect
    c.on_disconnect = on_disconnect
    c.connect_async(cfg.host, cfg.port, keepalive=cfg.keepalive)
    c.loop_start()
    return c


class _ClosedOnFailedHandshake(ssl.SSLSocket):
    """An ``SSLSocket`` that closes itself when its handshake fails (paho leaves such a
    socket open, on every failed attempt of its reconnect loop)."""

    def do_handshake(self, block: bool = False) -> None:
        try:
            super().do_handshake(block)
        except BaseException:
            self.close()
            raise


def tls_context(cfg: BrokerConfig) -> ssl.SSLContext:
    """The TLS context of a broker connection: TLS 1.2 or later, the broker's certificate
    and host name verified against ``cfg.cafile`` only (the system's authorities when
    none is given), this client's certificate when one is configured.

    Raises
    ------
    CutwatchError
        A file that is not a certificate or a key (or a key that is not the
        certificate's), naming it.
    """
    ctx = ssl.SSLContext(ssl.PROTOCOL_TLS_CLIENT)  # verifies the chain and the host name
    ctx.minimum_version = ssl.TLSVersion.TLSv1_2
    ctx.sslsocket_class = _ClosedOnFailedHandshake
    try:
        if cfg.cafile is not None:  # this authority only (not the system's as well)
            ctx.load_verify_locations(cafile=str(cfg.cafile))
        else:
            ctx.load_default_certs(ssl.Purpose.SERVER_AUTH)
    except (ssl.SSLError, ValueError) as exc:
        raise CutwatchError(
            f"broker CA file {str(cfg.cafile)!r}: expected PEM certificates ({exc})"
        ) from None
    try:
        if cfg.certfile is not None:
            ctx.load_cert_chain(
                str(cfg.certfile), str(cfg.keyfile) if cfg.keyfile is not None else None
            )
    except (ssl.SSLError, ValueError) as exc:
        raise CutwatchError(
            f"broker client certificate {str(cfg.certfile)!r}"
            + (f" with key {str(cfg.keyfile)!r}" if cfg.keyfile is not None else "")
            + f": expected a PEM certificate and its private key ({exc})"
        ) from None
    return ctx


def reason_text(reason_code: object) -> str:
    """A connect result as a person reads it (e.g. 'Not authorized')."""
    return str(reason_code)


def connect_blocking(client: object, cfg: BrokerConfig, timeout: float = 10.0) -> None:
    """Connect ``client`` (from :func:`make_client`), start its network thread and wait for
    the broker's answer.

    Raises
    ------
    CutwatchError
        The broker cannot be reached, refuses the credentials, or does not answer in
        ``timeout`` seconds; the message names the broker (never the password).
    """
    import threading

    import paho.mqtt.client as mqtt

    assert isinstance(client, mqtt.Client)
    done = threading.Event()
    result: list[str] = []

    def on_connect(_c: object, _u: object, _f: object, rc: object, _p: object = None) -> None:
        result.append("" if not getattr(rc, "is_failure", False) else reason_text(rc))
        done.set()

    def on_disconnect(_c: object, _u: object, _f: object, rc: object, _p: object = None) -> None:
        # the broker hung up before answering (a TLS client certificate it refused, or
        # plain MQTT on a TLS port)
        if not done.is_set():
            result.append(f"the broker closed the connection before answering ({rc})")
            done.set()

    client.on_connect = on_connect
    client.on_disconnect = on_disconnect
    try:
        client.connect(cfg.host, cfg.port, keepalive=cfg.keepalive)
    except (OSError, ssl.SSLError) as exc:
        raise CutwatchError(f"broker {cfg.describe()}: cannot connect ({exc})") from None
    client.loop_start()
    if not done.wait(timeout):
        client.loop_stop()
        raise CutwatchError(f"broker {cfg.describe()}: no answer within {timeout:g} s")
    if result[0]:
        client.loop_stop()
        client.disconnect()
        raise CutwatchError(f"broker {cfg.describe()}: connection refused: {result[0]}")
