"""The MQTT broker connection: address, credentials, TLS, topics, and the client.

The client is Eclipse paho-mqtt (2.x, callback API version 2). Why paho and not
aiomqtt: the live pipeline runs in its own thread, not on the event loop, and paho's
network thread hands messages to a thread-safe queue the loop drains at its own pace;
paho reconnects by itself with an exponential backoff (``reconnect_delay_set``), and
aiomqtt is itself a wrapper around paho for asyncio code. ``cutwatch feed`` and the
fleet page use the same client.

Topics (DESIGN "Broker"): ``cutwatch/<machine>/drive`` (blocks in),
``cutwatch/<machine>/meta`` (retained sidecar), ``cutwatch/<machine>/estimates`` (out).
"""

from __future__ import annotations

import re
import ssl
from dataclasses import dataclass
from pathlib import Path
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
    """Where and how to connect. ``url`` is ``mqtt://host[:port]`` or ``mqtts://...`` (TLS)."""

    host: str
    port: int
    tls: bool = False
    username: str | None = None
    password: str | None = None
    cafile: Path | None = None
    keepalive: int = 30

    def describe(self) -> str:
        """The address without the password (for logs and health)."""
        user = f"{self.username}@" if self.username else ""
        return f"{'mqtts' if self.tls else 'mqtt'}://{user}{self.host}:{self.port}"


def parse_broker_url(
    url: str,
    *,
    username: str | None = None,
    password: str | None = None,
    cafile: str | Path | None = None,
) -> BrokerConfig:
    """Parse ``mqtt://[user[:password]@]host[:port]`` (or ``mqtts://``, TLS, port 8883).

    Explicit ``username``/``password``/``cafile`` override the URL's. A ``cafile`` implies
    TLS.

    Raises
    ------
    CutwatchError
        The URL is not of that form, or the CA file does not exist.
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
    tls = parts.scheme == "mqtts" or cafile is not None
    ca = Path(cafile) if cafile else None
    if ca is not None and not ca.is_file():
        raise CutwatchError(f"broker CA file {str(ca)!r}: no such file")
    return BrokerConfig(
        host=parts.hostname,
        port=port or (8883 if tls else 1883),
        tls=tls,
        username=username if username is not None else unquote(parts.username or "") or None,
        password=password if password is not None else unquote(parts.password or "") or None,
        cafile=ca,
    )


def make_client(cfg: BrokerConfig, client_id: str = "") -> object:
    """A paho client set up for ``cfg`` (not yet connected).

    Returns ``paho.mqtt.client.Client`` (typed ``object`` here so paho is imported only
    where a broker is used).
    """
    import paho.mqtt.client as mqtt

    c = mqtt.Client(mqtt.CallbackAPIVersion.VERSION2, client_id=client_id, protocol=mqtt.MQTTv311)
    if cfg.username:
        c.username_pw_set(cfg.username, cfg.password)
    if cfg.tls:
        c.tls_set(ca_certs=str(cfg.cafile) if cfg.cafile else None, cert_reqs=ssl.CERT_REQUIRED)
    c.reconnect_delay_set(min_delay=1, max_delay=30)
    return c


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

    client.on_connect = on_connect
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
