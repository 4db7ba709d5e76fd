"""``cutwatch serve --source opcua`` against real OPC UA servers on loopback (issue 33).

The project's ``cutwatch opcua-sim`` (the machining centre with the CNC NodeSet imported,
secure) in a child process: ``cutwatch opcua browse`` writes the starter map, ``serve``
takes it; the spindle's values and the axes' identification reach the snapshot and the
stream, no sample is lost at the sampling interval the server revised; the sim is
killed and started again and the source recovers, the loop never stopping. Without the
sim's certificate in the trust list the server is refused, its thumbprint named. The
tests' own plain server (other node names, the map's short spelling, its own units)
is served too.
"""

from __future__ import annotations

import json
import math
import os
import signal
import subprocess
import sys
import tempfile
import time
from collections.abc import Iterator
from pathlib import Path

import httpx
import pytest
from _live import serve_process
from _opcua import MAP, plain_server

from server.pipeline.opcua_link import thumbprint

ROOT = Path(__file__).resolve().parents[2]


def _free_port() -> int:
    import socket

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


class Sim:
    """``cutwatch opcua-sim`` as a child process (``start``/``kill``)."""

    def __init__(self, d: Path) -> None:
        self.dir = d
        self.port = _free_port()
        self.proc: subprocess.Popen[str] | None = None
        self.log = tempfile.TemporaryFile(mode="w+")

    @property
    def url(self) -> str:
        return f"opc.tcp://127.0.0.1:{self.port}/cutwatch"

    @property
    def cert(self) -> Path:
        return self.dir / "sim" / "server-cert.der"

    def start(self) -> None:
        cmd = [sys.executable, "-m", "server.cli.main", "opcua-sim", "--port", str(self.port),
               "--cert-dir", str(self.dir / "sim")]  # fmt: skip
        self.proc = subprocess.Popen(cmd, stdout=self.log, stderr=subprocess.STDOUT, text=True)
        deadline = time.monotonic() + 60
        while time.monotonic() < deadline:
            self.log.seek(0)
            if "server certificate:" in self.log.read():
                return
            if self.proc.poll() is not None:
                break
            time.sleep(0.2)
        self.log.seek(0)
        raise AssertionError(f"opcua-sim did not start: {self.log.read()[-2000:]}")

    def kill(self) -> None:
        if self.proc is not None and self.proc.poll() is None:
            self.proc.send_signal(signal.SIGKILL)
            self.proc.wait(10)


@pytest.fixture(scope="module")
def sim(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Sim]:
    s = Sim(tmp_path_factory.mktemp("opcua-sim"))
    s.start()
    try:
        yield s
    finally:
        s.kill()
        s.log.close()


def _health(hp: str) -> dict:  # type: ignore[type-arg]
    return httpx.get(f"http://{hp}/api/health", timeout=10).json()


def _latest(hp: str) -> dict:  # type: ignore[type-arg]
    return httpx.get(f"http://{hp}/api/snapshot", timeout=10).json()["pipeline"]["latest"]


def _until(cond, seconds: float, what: str) -> None:  # type: ignore[no-untyped-def]
    end = time.monotonic() + seconds
    while time.monotonic() < end:
        if cond():
            return
        time.sleep(0.25)
    raise AssertionError(f"timed out waiting for {what}")


def _finite(v: object) -> bool:
    return isinstance(v, float | int) and math.isfinite(v)


def test_browse_then_serve_the_sim_spindle_and_axes_arrive_kill_and_recover(
    sim: Sim, tmp_path: Path
) -> None:
    nodes = tmp_path / "map.json"
    subprocess.run(
        [sys.executable, "-m", "server.cli.main", "opcua", "browse", sim.url,
         "--opcua-trust", str(sim.cert), "--opcua-cert-dir", str(tmp_path / "client"),
         "--out", str(nodes)],
        check=True, capture_output=True, timeout=60,
    )  # fmt: skip
    m = json.loads(nodes.read_text())
    assert m["axes"]["X"]["kind"] == "two_inertia" and m["axes"]["Y"]["kind"] == "rigid"
    assert m["axes"]["X"]["signals"]["q_m"].endswith("X.PosIndirect.ActPos")  # OPC 40502
    assert m["spindle"]["signals"]["speed"].endswith("S.ActSpeed")
    with serve_process(
        "--source", "opcua", "--opcua", sim.url, "--nodes", str(nodes),
        "--opcua-trust", str(sim.cert), "--data-dir", str(tmp_path / "data"),
    ) as sp:  # fmt: skip
        hp = sp.host
        _until(lambda: _health(hp)["opcua"]["taken"] >= 30, 40, "30 samples")
        _until(lambda: _finite(_latest(hp).get("X.Fv")), 30, "X's identification")
        h = _health(hp)
        o = h["opcua"]
        assert o["state"] == "connected" and o["policy"].endswith("/SignAndEncrypt")
        assert o["revised_sampling_s"] == pytest.approx(0.1) and o["queue_size"] >= 2
        # no sample lost (the server's Overflow, a gap) nor two in one cell at the revised
        # sampling; "late" (delivered after its cell went out: a server or client stalled
        # for longer than QUIET_S under load) is the grid's timing, reported, not asserted
        assert o["connects"] == 1 and o["gaps"] == 0, o  # the connection held
        assert o["lost"] == 0 and o["merged"] == 0, o
        assert "X.q_m: mm converted to m" in o["units"]
        parts = {p["name"]: p for p in h["parts"]}
        assert parts["cnc"]["running"] and parts["axes"]["running"]
        assert parts["spindle"]["running"]  # the cutting power over the taught idle
        assert "rotary two-inertia" in parts["stage"]["reason"]  # said, not run on X in m
        # the spindle turns (not at every moment: tool changes stop it)
        _until(lambda: 100 < (_latest(hp).get("spindle_speed") or 0) < 12_000, 60, "the spindle")
        latest = _latest(hp)
        assert _finite(latest["spindle_power"]) and _finite(latest["X.F"])
        assert _finite(latest["spindle.torque"]) and _finite(latest["spindle.current"])
        # the sim dies: the source says so, the loop goes on; it comes back: recovered
        sim.kill()
        _until(lambda: not _health(hp)["opcua"]["connected"], 20, "the lost connection")
        assert _health(hp)["status"] != "error"
        taken = _health(hp)["opcua"]["taken"]
        sim.start()
        _until(lambda: _health(hp)["opcua"]["connects"] >= 2, 60, "the reconnect")
        _until(lambda: _health(hp)["opcua"]["taken"] > taken + 10, 20, "samples again")
        o = _health(hp)["opcua"]
        assert o["gaps"] == 1 and o["state"] == "connected"
        assert sp.proc.poll() is None


def test_an_untrusted_server_is_refused_by_serve_naming_its_thumbprint(
    sim: Sim, tmp_path: Path
) -> None:
    nodes = tmp_path / "map.json"
    axis = {"kind": "rigid", "q_m": "ns=1;s=X.PosIndirect.ActPos", "i_m": "ns=1;s=X.ActCurrent"}
    nodes.write_text(json.dumps({"sample_time": 0.1, "axes": {"X": axis}}))
    with serve_process(
        "--source", "opcua", "--opcua", sim.url, "--nodes", str(nodes),
        "--data-dir", str(tmp_path / "data"),
    ) as sp:  # fmt: skip
        _until(lambda: _health(sp.host)["opcua"]["state"].startswith("refused"), 30, "refusal")
        o = _health(sp.host)["opcua"]
    assert f"thumbprint {thumbprint(sim.cert.read_bytes())}" in o["state"]
    assert o["taken"] == 0


def test_serve_takes_a_plain_server_of_other_names_in_the_short_spelling(tmp_path: Path) -> None:
    nodes = tmp_path / "plain.json"
    nodes.write_text(json.dumps(MAP))
    with plain_server(tmp_path) as srv, serve_process(
        "--source", "opcua", "--opcua", srv.url, "--nodes", str(nodes),
        "--opcua-trust", str(srv.cert), "--data-dir", str(tmp_path / "data"),
    ) as sp:  # fmt: skip
        hp = sp.host
        _until(lambda: _finite(_latest(hp).get("X.Fv")), 40, "X's identification")
        latest = _latest(hp)
        o = _health(hp)["opcua"]
    assert 5400 < latest["spindle_speed"] < 6600 and 1400 < latest["spindle_power"] < 2600
    assert _finite(latest["X.Fc"]) and "X.M" in latest  # the mass: given an acceleration
    assert o["lost"] == 0 and o["policy"] == "Basic256Sha256/SignAndEncrypt"
    assert os.path.basename(str(nodes)) == "plain.json"
