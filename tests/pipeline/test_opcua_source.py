"""The OPC UA source against a real asyncua server on loopback (tests/_opcua.py).

The server of the tests' own: its node names, its units (mm, 1/min, kW), Basic256Sha256
SignAndEncrypt. The source must take the server's samples on the grid of the sampling
interval it revised, convert the engineering units, lose none, and refuse an untrusted
server naming its thumbprint. A server killed and started again: the sim under
`cutwatch serve` (tests/service/test_opcua_service.py) and the grid's gap
(tests/pipeline/test_opcua_grid.py).
"""

from __future__ import annotations

import time
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest
from _opcua import MAP, PlainServer, plain_server

from server.pipeline.opcua_link import OpcuaSecurity, thumbprint
from server.pipeline.opcua_source import OpcuaOptions, OpcuaSource
from server.records.opcua_map import node_map_from_dict


@pytest.fixture(scope="module")
def certs(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The certificates of the module's servers and client (made once)."""
    return tmp_path_factory.mktemp("opcua-certs")


@pytest.fixture(scope="module")
def secure(certs: Path) -> Iterator[PlainServer]:
    """One Basic256Sha256 server for the tests that do not stop it."""
    with plain_server(certs) as srv:
        yield srv


def _source(url: str, certs: Path, trust: tuple[Path, ...], policy: str = "best") -> OpcuaSource:
    sec = OpcuaSecurity(policy=policy, trust=trust, cert_dir=certs / "client")
    return OpcuaSource(node_map_from_dict(MAP), OpcuaOptions(url, security=sec, backoff_max_s=1.0))


def _take(src: OpcuaSource, seconds: float, need: int = 1) -> list:  # type: ignore[type-arg]
    """The blocks ``src`` gives over ``seconds`` of wall time and on until ``need`` samples
    are in (a deadline of 30 s more): a loaded box's server may sample fewer in the
    window (the count was asserted of the window alone)."""
    out = []
    end = time.monotonic() + seconds
    while time.monotonic() < end or (
        sum(b.n for b in out) < need and time.monotonic() < end + 30.0
    ):
        b = src.step(1000)
        if b.n:
            out.append(b)
        time.sleep(0.05)
    return out


def _wait(cond, seconds: float = 20.0) -> None:  # type: ignore[no-untyped-def]
    end = time.monotonic() + seconds
    while time.monotonic() < end:
        if cond():
            return
        time.sleep(0.05)
    raise AssertionError("timed out")


def test_samples_arrive_on_the_revised_grid_in_si_units_and_none_is_lost(
    secure: PlainServer, certs: Path
) -> None:
    src = _source(secure.url, certs, (secure.cert,))
    src.start()
    try:
        _wait(lambda: src.link.info.connects >= 1)
        blocks = _take(src, 3.0, need=20)
    finally:
        src.stop()
    st = src.status()
    assert st["policy"] == "Basic256Sha256/SignAndEncrypt"
    assert st["revised_sampling_s"] == pytest.approx(0.1)
    assert st["queue_size"] >= 2  # publishing 0.1 / sampling 0.1 + 1
    n = sum(b.n for b in blocks)
    assert n >= 20, st
    t = np.concatenate([b.meas.t for b in blocks])
    np.testing.assert_allclose(np.diff(t), 0.1, atol=1e-9)  # one grid, no hole
    assert st["lost"] == 0 and st["late"] == 0 and st["merged"] == 0, st
    # the values are the server's, converted from mm, mm/s, 1/min, kW by EngineeringUnits
    b = blocks[-1]
    q = b.columns["ns=2;s=mill/X/position"]
    assert np.all(np.abs(q) <= 0.05 + 1e-9) and np.ptp(np.concatenate(
        [x.columns["ns=2;s=mill/X/position"] for x in blocks])) > 0.01  # fmt: skip
    np.testing.assert_allclose(b.meas.q_m, q)
    power = b.columns["ns=2;s=mill/S/power"]
    assert np.all((power > 1400) & (power < 2600))  # kW -> W
    speed = b.columns["ns=2;s=mill/S/speed"]
    assert np.all((speed > 5400) & (speed < 6600))
    assert any(
        "mill/S/power" not in u and "spindle.power: kW converted to W" in u for u in st["units"]
    )
    # the current times K_t is the effort the axis identification reads
    np.testing.assert_allclose(b.meas.tau_m, b.meas.i_m * 25.0)
    # the tool changes rarely: it is held and the holds are counted
    assert st["held"]["ns=2;s=mill/tool"] > 0
    assert st["held"]["ns=2;s=mill/X/position"] == 0


def test_an_untrusted_server_is_refused_naming_its_thumbprint(
    secure: PlainServer, certs: Path
) -> None:
    src = _source(secure.url, certs, ())
    src.start()
    try:
        _wait(lambda: src.link.info.state.startswith("refused"))
        assert src.step(100).n == 0
    finally:
        src.stop()
    tp = thumbprint(secure.cert.read_bytes())
    st = src.status()
    assert f"untrusted server certificate, thumbprint {tp}" in st["state"]
    assert st["connects"] == 0 and st["taken"] == 0


def test_security_none_only_when_named(certs: Path) -> None:
    with plain_server(certs, secure=False) as srv:
        src = _source(srv.url, certs, ())
        src.start()
        try:
            _wait(lambda: src.link.info.state.startswith("refused"))
        finally:
            src.stop()
        assert "offers no endpoint of Aes256_Sha256_RsaPss" in src.status()["state"]
        assert "None/None_" in src.status()["state"]
        named = _source(srv.url, certs, (), policy="None")
        named.start()
        try:
            _wait(lambda: named.link.info.connects >= 1)
            assert sum(b.n for b in _take(named, 1.0)) > 0
        finally:
            named.stop()


def test_the_sampling_interval_the_server_revised_is_adopted_and_said(
    secure: PlainServer, certs: Path
) -> None:
    # asked for 50 ms, published every 100 ms: asyncua's server revises the sampling
    # interval to the publishing interval (100 ms), as a CNC limited to 100 ms would
    m = dict(MAP, sample_time=0.05)
    sec = OpcuaSecurity(trust=(secure.cert,), cert_dir=certs / "client")
    src = OpcuaSource(node_map_from_dict(m), OpcuaOptions(secure.url, 0.1, sec, 1.0))
    assert src.sample_time == 0.05
    src.start()
    try:
        _wait(lambda: src.needs_rebuild)
        assert src.step(100).n == 0  # nothing on the wrong grid
        new = src.renewed()  # what the live loop does: a pipeline at the revised rate
        assert new.sample_time == pytest.approx(0.1) and not new.needs_rebuild
        blocks = _take(new, 2.0, need=10)
    finally:
        src.stop()
    st = new.status()
    assert st["sampling_note"] == "the server revised the sampling interval from 0.05 s to 0.1 s"
    assert st["queue_size"] == 3  # publishing 0.1 / sampling 0.05 + 1, as asked
    t = np.concatenate([b.meas.t for b in blocks])
    assert len(t) >= 10 and np.allclose(np.diff(t), 0.1)
    assert st["lost"] == 0 and st["merged"] == 0
