"""``cutwatch worker --opcua-machine`` against a real ``cutwatch opcua-sim`` on loopback
(issue 33): the worker reads the machine from the sim's OPC UA server (secure, the sim's
certificate trusted, the map ``cutwatch opcua browse`` wrote) and publishes its estimates
on a real Mosquitto as it publishes a broker machine's: the machine's name, the source
``opcua``, the axes' identified parameters, the OPC UA connection's health in ``feed``.
The sim is killed and started again: the machine's source reconnects by itself and its
estimates go on, the worker never stopping. Bad entries are refused naming the key.
"""

from __future__ import annotations

import itertools
import json
import math
import signal
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import httpx
import pytest
from _broker import broker, free_port
from _proc import stop
from test_worker import Estimates

from server.errors import CutwatchError
from server.pipeline.opcua_link import OpcuaSecurity
from server.pipeline.opcua_machines import load_opcua_machines, parse_opcua_machine

pytestmark = pytest.mark.slow

MACHINE = "cnc-7"


def _cutwatch(*args: str) -> list[str]:
    return [sys.executable, "-m", "server.cli.main", *args]


def _wait(cond: Any, timeout: float, what: str) -> None:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if cond():
            return
        time.sleep(0.2)
    raise AssertionError(f"not within {timeout:g} s: {what}")


class Sim:
    """``cutwatch opcua-sim`` on a fixed free port (``start`` again after ``kill``)."""

    def __init__(self, d: Path) -> None:
        self.dir, self.port = d, free_port()
        self.url = f"opc.tcp://127.0.0.1:{self.port}/cutwatch"
        self.cert = d / "sim" / "server-cert.der"
        self.proc: subprocess.Popen[bytes] | None = None

    def start(self) -> None:
        log = self.dir / "sim.log"
        with log.open("w") as f:
            self.proc = subprocess.Popen(
                _cutwatch("opcua-sim", "--port", str(self.port), "--cert-dir",
                          str(self.dir / "sim")),
                stdout=f, stderr=subprocess.STDOUT,
            )  # fmt: skip
        _wait(lambda: "server certificate:" in log.read_text(), 60, "the sim")

    def kill(self) -> None:
        if self.proc is not None and self.proc.poll() is None:
            self.proc.send_signal(signal.SIGKILL)
            self.proc.wait(10)


@pytest.fixture
def sim(tmp_path: Path) -> Iterator[dict[str, Any]]:
    """A real opcua-sim on a free port, and the map browsed from it."""
    s = Sim(tmp_path)
    try:
        s.start()
        nodes = tmp_path / "map.json"
        subprocess.run(
            _cutwatch("opcua", "browse", s.url, "--opcua-trust", str(s.cert),
                      "--opcua-cert-dir", str(tmp_path / "client"), "--out", str(nodes)),
            check=True, capture_output=True, timeout=60,
        )  # fmt: skip
        yield {"url": s.url, "cert": s.cert, "nodes": nodes, "dir": tmp_path, "sim": s}
    finally:
        s.kill()


def _finite(v: object) -> bool:
    return isinstance(v, float | int) and math.isfinite(v)


def test_a_worker_publishes_an_opcua_machines_estimates(sim: dict[str, Any]) -> None:
    d: Path = sim["dir"]
    http = free_port()
    with broker() as port:
        est = Estimates(port)
        spec = f"{MACHINE}={sim['url']},nodes={sim['nodes']},trust={sim['cert']}"
        w = subprocess.Popen(
            _cutwatch("worker", "--broker", f"mqtt://127.0.0.1:{port}", "--port", str(http),
                      "--data-dir", str(d / "plant"), "--opcua-cert-dir", str(d / "client"),
                      "--opcua-machine", spec),
            stdout=subprocess.DEVNULL, stderr=subprocess.PIPE,
        )  # fmt: skip
        try:

            def identified() -> bool:
                e = est.of(MACHINE)
                return bool(e) and _finite(e[-1]["params"].get("X.Fv"))

            _wait(identified, 60, f"{MACHINE}'s estimates with X's identification")
            msgs = est.of(MACHINE)
            last = msgs[-1]
            assert last["machine"] == MACHINE and last["source"] == "opcua"
            ts = [m["t"] for m in msgs]
            assert all(b > a for a, b in itertools.pairwise(ts)), ts
            f = last["feed"]
            assert f["connected"] is True and f["server"] == sim["url"], f
            assert f["policy"].endswith("/SignAndEncrypt") and f["taken"] > 0, f
            assert f["lost"] == 0, f  # no sample lost at the revised sampling interval
            assert last["health"]["runtime"].startswith("worker"), last["health"]
            assert not last["alarms"], last["alarms"]
            h = httpx.get(f"http://127.0.0.1:{http}/api/health", timeout=5).json()
            assert h["status"] == "ok" and h["machines"] == 1 and h["opcua_connected"] == 1, h
            m = httpx.get(f"http://127.0.0.1:{http}/api/machines", timeout=5).json()
            assert [r["machine"] for r in m] == [MACHINE]
            # the server dies: the machine's source says so, the worker goes on; it comes
            # back: the source reconnects by itself and the estimates go on
            one = f"http://127.0.0.1:{http}/api/machines/{MACHINE}"

            def feed() -> dict[str, Any]:
                r: dict[str, Any] = httpx.get(one, timeout=5).json()["feed"]
                return r

            sim["sim"].kill()
            _wait(lambda: not feed()["connected"], 20, "the lost connection")
            h = httpx.get(f"http://127.0.0.1:{http}/api/health", timeout=5).json()
            assert h["status"] == "ok" and h["opcua_connected"] == 0, h
            sim["sim"].start()
            back = time.time()
            _wait(lambda: feed()["connects"] >= 2, 60, "the reconnect")
            _wait(lambda: len(est.of(MACHINE, back)) >= 10, 30, "estimates again")
            again = est.of(MACHINE, back)[-1]
            assert again["t"] > last["t"] and again["feed"]["connected"] is True, again["feed"]
            assert again["feed"]["gaps"] == 1, again["feed"]  # the outage, counted once
            print(json.dumps({"messages": len(msgs), "t": last["t"], "params": last["params"]}))
        finally:
            est.close()
            stop(w)
        # SIGTERM: the machine's checkpoint written as a broker machine's is
        assert (d / "plant" / "state" / f"{MACHINE}.npz").is_file()


def test_bad_opcua_machines_are_refused_naming_the_key(tmp_path: Path) -> None:
    sec = OpcuaSecurity()
    nodes = tmp_path / "map.json"
    nodes.write_text("{}")
    ok = parse_opcua_machine(f"m1=opc.tcp://h:4840,nodes={nodes},trust=a.der,trust=b.der", sec)
    assert ok.name == "m1" and ok.options.url == "opc.tcp://h:4840"
    assert [p.name for p in ok.options.security.trust] == ["a.der", "b.der"]
    cases = {
        "m1=http://h,nodes=x": "--opcua-machine m1.url: expected opc.tcp://",
        f"m1=opc.tcp://h:4840,nodes={nodes},colour=red": "m1.colour: expected one of the keys",
        "m1=opc.tcp://h:4840,nodes=nope.json": "m1.nodes: expected a node map file",
        f"m1=opc.tcp://h:4840,nodes={nodes},security=Basic128": "m1.security: OPC UA security",
        f"m1=opc.tcp://h:4840,nodes={nodes},publishing=0": "m1.publishing: expected 0.01-10 s",
        f"m1=opc.tcp://h:4840,nodes={nodes},cert=c.pem": "m1.cert/key: expected both",
        "bad name=opc.tcp://h:4840": "machine name 'bad name'",
    }
    for spec, said in cases.items():
        with pytest.raises(CutwatchError) as ei:
            parse_opcua_machine(spec, sec)
        assert said in str(ei.value), (spec, str(ei.value))
    f = tmp_path / "ua.json"
    f.write_text(json.dumps({"machines": {"m2": {"url": "opc.tcp://h:4840", "nodes": "map.json",
                                                 "security": "None"}}}))  # fmt: skip
    (m2,) = load_opcua_machines(f, sec)
    assert m2.nodes == nodes and m2.options.security.policy == "None"
    f.write_text(json.dumps({"machines": {"m2": {"url": "opc.tcp://h:4840"}}}))
    with pytest.raises(CutwatchError, match=r"machines\.m2\.nodes: expected a node map file"):
        load_opcua_machines(f, sec)
