"""cutwatch's MQTT clients over TLS to a real Mosquitto, with a certificate authority
generated for the test: the broker's certificate verified, client certificates, refusals
that name the reason, and the options of ``serve``, ``feed`` and ``fleet``."""

from __future__ import annotations

import argparse
import queue
from pathlib import Path

import paho.mqtt.client as mqtt
import pytest
from _broker import Pki, broker, make_pki, tls_listener

from server.cli.broker_options import add_broker_options, broker_config
from server.cli.commands.serve import add_arguments as serve_arguments
from server.cli.commands.serve import build_settings
from server.errors import CutwatchError
from server.pipeline.broker import connect_blocking, make_client, parse_broker_url
from server.service.loop import broker_config as service_broker_config


@pytest.fixture(scope="module")
def pki(tmp_path_factory: pytest.TempPathFactory) -> Pki:
    return make_pki(tmp_path_factory.mktemp("pki"))


def roundtrip(url: str, **files: Path) -> bytes:
    """Connect a subscriber and a publisher with cutwatch's client; one message across."""
    cfg = parse_broker_url(url, **files)  # type: ignore[arg-type]
    got: queue.Queue[bytes] = queue.Queue()
    sub = make_client(cfg, "sub")
    pub = make_client(cfg, "pub")
    assert isinstance(sub, mqtt.Client) and isinstance(pub, mqtt.Client)
    sub.on_message = lambda _c, _u, m: got.put(bytes(m.payload))
    connect_blocking(sub, cfg, timeout=5)
    try:
        sub.subscribe("cutwatch/m1/drive", qos=1)[1]
        connect_blocking(pub, cfg, timeout=5)
        try:
            # until the subscription is in place, a message may be missed: repeat
            for _ in range(50):
                pub.publish("cutwatch/m1/drive", b"over tls", qos=1).wait_for_publish(5)
                try:
                    return got.get(timeout=0.2)
                except queue.Empty:
                    continue
            raise AssertionError("no message came through")
        finally:
            pub.loop_stop()
            pub.disconnect()
    finally:
        sub.loop_stop()
        sub.disconnect()


def test_tls_with_the_ca_carries_messages_and_other_cas_are_refused(pki: Pki) -> None:
    with broker(tls=tls_listener(pki)) as port:
        # by address and by name: the certificate names both
        assert roundtrip(f"mqtts://127.0.0.1:{port}", cafile=pki.ca) == b"over tls"
        assert roundtrip(f"mqtts://localhost:{port}", cafile=pki.ca) == b"over tls"
        # a client trusting another authority refuses the broker's certificate
        cfg = parse_broker_url(f"mqtts://127.0.0.1:{port}", cafile=pki.rogue_ca)
        with pytest.raises(CutwatchError, match="certificate verify failed"):
            connect_blocking(make_client(cfg), cfg, timeout=5)
        # so does one trusting only the system's authorities (no --cafile)
        cfg = parse_broker_url(f"mqtts://127.0.0.1:{port}")
        with pytest.raises(CutwatchError, match="certificate verify failed"):
            connect_blocking(make_client(cfg), cfg, timeout=5)
        # plain MQTT to the TLS port: the broker hangs up
        cfg = parse_broker_url(f"mqtt://127.0.0.1:{port}")
        with pytest.raises(CutwatchError, match=r"closed the connection|no answer"):
            connect_blocking(make_client(cfg), cfg, timeout=2)


def test_a_broker_requiring_client_certificates(pki: Pki) -> None:
    with broker(tls=tls_listener(pki, require_certificate=True)) as port:
        url = f"mqtts://127.0.0.1:{port}"
        got = roundtrip(url, cafile=pki.ca, certfile=pki.client_cert, keyfile=pki.client_key)
        assert got == b"over tls"
        # without a certificate, or with one from another authority: no session
        for files in ({}, {"certfile": pki.rogue_client_cert, "keyfile": pki.rogue_client_key}):
            cfg = parse_broker_url(url, cafile=pki.ca, **files)  # type: ignore[arg-type]
            c = make_client(cfg)
            with pytest.raises(CutwatchError, match=r"broker mqtts://127\.0\.0\.1"):
                connect_blocking(c, cfg, timeout=3)
            assert isinstance(c, mqtt.Client)
            c.loop_stop()


def test_bad_tls_files_are_named(pki: Pki, tmp_path: Path) -> None:
    url = "mqtts://127.0.0.1:8883"
    with pytest.raises(CutwatchError, match=r"client certificate '.*nope\.crt': no such file"):
        parse_broker_url(url, certfile=tmp_path / "nope.crt")
    with pytest.raises(CutwatchError, match=r"client key .*: expected a client certificate"):
        parse_broker_url(url, keyfile=pki.client_key)
    junk = tmp_path / "junk.pem"
    junk.write_text("not a certificate\n")
    with pytest.raises(CutwatchError, match=r"CA file '.*junk\.pem': expected PEM"):
        make_client(parse_broker_url(url, cafile=junk))
    # a key that is not the certificate's
    cfg = parse_broker_url(url, certfile=pki.client_cert, keyfile=pki.rogue_client_key)
    with pytest.raises(CutwatchError, match=r"client certificate .* with key .*rogue-client"):
        make_client(cfg)
    # TLS is implied by a CA file or a client certificate
    assert parse_broker_url("mqtt://h", cafile=pki.ca).tls
    assert parse_broker_url("mqtt://h", certfile=pki.client_cert).port == 8883


def test_the_options_of_serve_feed_and_fleet(pki: Pki, monkeypatch: pytest.MonkeyPatch) -> None:
    # feed and fleet: flags, with the environment as their defaults
    monkeypatch.setenv("CUTWATCH_MQTT_CAFILE", str(pki.ca))
    monkeypatch.setenv("CUTWATCH_MQTT_PASSWORD", "pw-from-env")
    p = argparse.ArgumentParser()
    add_broker_options(p)
    args = p.parse_args(
        ["--username", "m1", "--certfile", str(pki.client_cert), "--keyfile", str(pki.client_key)]
    )
    cfg = broker_config("mqtts://broker.example", args)
    assert (cfg.cafile, cfg.certfile, cfg.keyfile) == (pki.ca, pki.client_cert, pki.client_key)
    assert (cfg.username, cfg.password, cfg.tls, cfg.port) == ("m1", "pw-from-env", True, 8883)
    # serve: the same flags become the service's settings, which build the same connection
    p = argparse.ArgumentParser()
    serve_arguments(p)
    settings = build_settings(
        p.parse_args(
            ["--source", "mqtt", "--broker", "mqtts://broker.example:8884", "--username",
             "cutwatch", "--certfile", str(pki.client_cert), "--keyfile", str(pki.client_key)]
        )
    )  # fmt: skip
    cfg = service_broker_config(settings)
    assert (cfg.host, cfg.port, cfg.tls, cfg.username) == ("broker.example", 8884, True, "cutwatch")
    assert (cfg.cafile, cfg.certfile, cfg.keyfile) == (pki.ca, pki.client_cert, pki.client_key)
    assert cfg.password == "pw-from-env"
