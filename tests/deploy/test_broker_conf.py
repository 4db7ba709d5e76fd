"""The shipped broker configuration (deploy/mosquitto/) loaded by a real Mosquitto: TLS
only, no anonymous clients, and the access list's rules: an edge device publishes drive
data and meta for its own machine only; only cutwatch publishes estimates, events and
commands; cutwatch's own clients (``serve --source mqtt``, ``feed``) work through it."""

from __future__ import annotations

import contextlib
import json
import queue
import shutil
import threading
import time
import uuid
from collections.abc import Iterator
from pathlib import Path

import httpx
import paho.mqtt.client as mqtt
import pytest
from _broker import Pki, free_port, make_pki, mosquitto, password_file
from _live import serve, serve_fleet
from _wait import poll

from server.cli.main import main
from server.errors import CutwatchError
from server.pipeline.broker import BrokerConfig, connect_blocking, make_client, parse_broker_url
from server.records.drive_wire import encode_estimates

SHIPPED = Path(__file__).resolve().parents[2] / "deploy" / "mosquitto"
INSTALLED = "/etc/mosquitto/cutwatch/"  # where the shipped conf expects its files
USERS = {"cutwatch": "svc-pw-1", "viewer": "view-pw-2", "m1": "dev-pw-3", "m2": "dev-pw-4"}


@pytest.fixture(scope="module")
def shipped_broker(tmp_path_factory: pytest.TempPathFactory) -> Iterator[tuple[int, Pki]]:
    """Mosquitto with deploy/mosquitto/mosquitto.conf as a conf.d drop-in (as on Debian),
    its files where it names them (a temporary directory standing for /etc/...), the
    shipped acl verbatim, and a password file made as docs/broker.md says."""
    d = tmp_path_factory.mktemp("mosq")
    pki = make_pki(d / "pki")
    port = free_port()
    etc = d / "etc"
    (d / "conf.d").mkdir()
    etc.mkdir()
    for src, name in ((pki.ca, "ca.crt"), (pki.server_cert, "server.crt"),
                      (pki.server_key, "server.key")):  # fmt: skip
        shutil.copy(src, etc / name)
    shutil.copy(SHIPPED / "acl", etc / "acl")
    password_file(etc / "passwd", USERS)
    conf = (SHIPPED / "mosquitto.conf").read_text()
    # only the port (8883 is not ours to take here) and the directory change
    assert "\nlistener 8883\n" in conf and conf.count(INSTALLED) == 6
    conf = conf.replace("\nlistener 8883\n", f"\nlistener {port} 127.0.0.1\n")
    (d / "conf.d" / "cutwatch.conf").write_text(conf.replace(INSTALLED, f"{etc}/"))
    with mosquitto([f"include_dir {d / 'conf.d'}"], port, d):
        yield port, pki


def config(port: int, pki: Pki, user: str | None) -> BrokerConfig:
    return parse_broker_url(
        f"mqtts://localhost:{port}",
        username=user,
        password=USERS.get(user or ""),
        cafile=pki.ca,
    )


@contextlib.contextmanager
def client(port: int, pki: Pki, user: str, topics: tuple[str, ...] = ()) -> Iterator[tuple]:
    """A connected client of ``user`` (cutwatch's own client code) subscribed to
    ``topics``; yields it and the queue of (topic, payload) it receives."""
    cfg = config(port, pki, user)
    c = make_client(cfg, f"{user}-{uuid.uuid4().hex[:8]}")
    assert isinstance(c, mqtt.Client)
    got: queue.Queue[tuple[str, bytes]] = queue.Queue()
    c.on_message = lambda _c, _u, m: got.put((m.topic, bytes(m.payload)))
    connect_blocking(c, cfg, timeout=5)
    subscribed = threading.Event()
    c.on_subscribe = lambda *_a: subscribed.set()
    try:
        if topics:
            c.subscribe([(t, 1) for t in topics])
            assert subscribed.wait(5)
        yield c, got
    finally:
        c.loop_stop()
        c.disconnect()


def received_until(got: queue.Queue, sentinel: tuple[str, bytes]) -> list[tuple[str, bytes]]:
    """Everything received up to and including ``sentinel`` (published last, QoS 1, by the
    same client as the messages before it: the broker keeps their order)."""
    out: list[tuple[str, bytes]] = []
    deadline = time.monotonic() + 10
    while time.monotonic() < deadline:
        try:
            out.append(got.get(timeout=0.5))
        except queue.Empty:
            continue
        if out[-1] == sentinel:
            return out
    raise AssertionError(f"the sentinel {sentinel} never arrived; got {out}")


def publish_all(c: mqtt.Client, msgs: list[tuple[str, bytes]]) -> None:
    for t, body in msgs:
        c.publish(t, body, qos=1).wait_for_publish(5)


def test_a_device_publishes_only_its_own_machines_drive_and_meta(
    shipped_broker: tuple[int, Pki],
) -> None:
    port, pki = shipped_broker
    with client(port, pki, "cutwatch", ("cutwatch/#",)) as (_svc, at_cutwatch):
        with client(port, pki, "viewer", ("cutwatch/#",)) as (_v, at_viewer):
            with client(port, pki, "m2") as (m2, _):
                allowed = [("cutwatch/m2/drive", b"m2 drive"), ("cutwatch/m2/meta", b"m2 meta")]
                refused = [
                    ("cutwatch/m1/drive", b"m2 posing as m1"),
                    ("cutwatch/m1/meta", b"m2 posing as m1"),
                    ("cutwatch/m2/estimates", b"m2 forging estimates"),
                    ("cutwatch/m2/events", b"m2 forging events"),
                    ("cutwatch/m2/command", b"m2 forging a command"),
                    ("cutwatch/other/drive", b"m2 elsewhere"),
                ]
                publish_all(m2, [*refused, *allowed])
                got = received_until(at_cutwatch, allowed[-1])
            assert got == allowed  # nothing refused reached cutwatch, in order
            # the viewer reads estimates and events only: nothing of the device reached it
            with client(port, pki, "cutwatch") as (svc, _):
                out = [(f"cutwatch/m1/{leaf}", f"from cutwatch {leaf}".encode())
                       for leaf in ("estimates", "events")]  # fmt: skip
                publish_all(svc, out)
                assert received_until(at_viewer, out[-1]) == out


def test_only_cutwatch_publishes_commands_and_a_device_reads_its_own(
    shipped_broker: tuple[int, Pki],
) -> None:
    port, pki = shipped_broker
    with client(port, pki, "m1", ("cutwatch/+/command",)) as (_m1, at_m1):
        with client(port, pki, "viewer") as (viewer, _):
            publish_all(viewer, [("cutwatch/m1/command", b"viewer: feed hold")])
        with client(port, pki, "m2") as (m2, _):
            publish_all(m2, [("cutwatch/m1/command", b"m2: feed hold")])
        with client(port, pki, "cutwatch") as (svc, _):
            msgs = [("cutwatch/m2/command", b"not for m1"), ("cutwatch/m1/command", b"hold")]
            publish_all(svc, msgs)
        # the viewer's and m2's commands were dropped; m2's command is not m1's to read
        assert received_until(at_m1, msgs[-1]) == [msgs[-1]]


def test_anonymous_wrong_password_and_plain_text_are_refused(
    shipped_broker: tuple[int, Pki],
) -> None:
    port, pki = shipped_broker
    for cfg in (
        config(port, pki, None),
        parse_broker_url(
            f"mqtts://localhost:{port}", username="m1", password="wrong", cafile=pki.ca
        ),
        parse_broker_url(f"mqtt://127.0.0.1:{port}", username="m1", password=USERS["m1"]),
    ):
        c = make_client(cfg)
        with pytest.raises(CutwatchError, match=r"refused|no answer") as e:
            connect_blocking(c, cfg, timeout=5)
        assert USERS["m1"] not in str(e.value)
        assert isinstance(c, mqtt.Client)
        c.loop_stop()


def test_serve_and_feed_through_the_shipped_broker(
    shipped_broker: tuple[int, Pki], tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """``cutwatch feed`` as device m1 and the service as user cutwatch, both over TLS: the
    service receives m1's drive data and its estimates reach the viewer."""
    port, pki = shipped_broker
    log = tmp_path / "run.csv"
    assert main(["simulate", "--out", str(log), "--seconds", "3"]) == 0
    url = f"mqtts://localhost:{port}"
    with (
        client(port, pki, "viewer", ("cutwatch/m1/estimates",)) as (_v, at_viewer),
        serve(
            source="mqtt",
            mqtt_broker=url,
            mqtt_machine="m1",
            mqtt_publish_hz=10,
            mqtt_username="cutwatch",
            mqtt_password=USERS["cutwatch"],
            mqtt_cafile=pki.ca,
        ) as hp,
    ):
        deadline = time.monotonic() + 10
        while not httpx.get(f"http://{hp}/api/health").json()["feed"]["connected"]:
            assert time.monotonic() < deadline, "the service never connected"
            time.sleep(0.1)
        monkeypatch.setenv("CUTWATCH_MQTT_PASSWORD", USERS["m1"])
        argv = ["feed", str(log), "--broker", url, "--machine", "m1", "--quiet",
                "--username", "m1", "--cafile", str(pki.ca)]  # fmt: skip
        assert main(argv) == 0
        health = httpx.get(f"http://{hp}/api/health").json()
        assert health["feed"]["blocks"] >= 50 and health["feed"]["gaps"] == 0, health
        assert health["estimates_out"]["published"] > 0, health
        topic, body = at_viewer.get(timeout=20)
        assert topic == "cutwatch/m1/estimates"
        assert json.loads(body)["schema"] == "cutwatch.estimates"


def test_the_fleet_page_reads_estimates_as_viewer(shipped_broker: tuple[int, Pki]) -> None:
    """``cutwatch fleet``'s app logged in as viewer over TLS: a row appears for what
    cutwatch publishes, none for estimates a device tried to forge."""
    port, pki = shipped_broker
    with serve_fleet(config(port, pki, "viewer"), stale_after=30.0) as hp:
        poll(lambda: httpx.get(f"http://{hp}/api/health").json()["connected"], 10)
        with client(port, pki, "m2") as (m2, _):
            publish_all(m2, [("cutwatch/m2/estimates", encode_estimates("m2", {"wall": 1.0}))])
        with client(port, pki, "cutwatch") as (svc, _):
            publish_all(svc, [("cutwatch/m1/estimates", encode_estimates("m1", {"wall": 1.0}))])
        rows = poll(lambda: httpx.get(f"http://{hp}/api/fleet").json(), 10)
        assert [r["machine"] for r in rows] == ["m1"]
