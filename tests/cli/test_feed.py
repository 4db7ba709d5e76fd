"""``cutwatch feed`` through a real Mosquitto: what a subscriber receives is the log."""

from __future__ import annotations

import contextlib
import queue
import subprocess
import sys
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np
import paho.mqtt.client as mqtt
import pytest
from _broker import broker

from server.cli.main import main
from server.records.drive_wire import decode_drive, decode_meta
from server.records.measured_log import load_log


@pytest.fixture(scope="module")
def log(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("feed") / "run.csv"
    assert main(["simulate", "--out", str(out), "--seconds", "2"]) == 0
    return out


def subscriber(port: int, topics: list[str], auth: tuple[str, str] | None = None) -> tuple:
    got: queue.Queue[tuple[str, bytes, bool]] = queue.Queue()
    c = mqtt.Client(mqtt.CallbackAPIVersion.VERSION2)
    if auth:
        c.username_pw_set(*auth)
    c.on_message = lambda _c, _u, m: got.put((m.topic, m.payload, bool(m.retain)))
    acked: queue.Queue[int] = queue.Queue()
    c.on_subscribe = lambda _c, _u, mid, _rc, _p: acked.put(mid)
    c.connect("127.0.0.1", port)
    mids = {c.subscribe(t, qos=1)[1] for t in topics}
    c.loop_start()
    # every subscription acknowledged before anything is published (was a fixed 0.3 s)
    while mids:
        mids.discard(acked.get(timeout=30))
    return c, got


def test_feed_carries_the_log_to_a_subscriber(log: Path) -> None:
    with broker() as port:
        c, got = subscriber(port, ["cutwatch/m1/#"])
        try:
            rc = main(
                ["feed", str(log), "--broker", f"mqtt://127.0.0.1:{port}", "--machine", "m1",
                 "--speed", "0", "--quiet"]
            )  # fmt: skip
            assert rc == 0
            # every sample of the log received (30 s; was: until a 1 s pause, which a loaded
            # box could put mid-stream), then until a 1 s pause: nothing more may follow
            want, have = load_log(log).n, 0
            msgs = []
            deadline = time.monotonic() + 30
            while have < want and time.monotonic() < deadline:
                with contextlib.suppress(queue.Empty):
                    msgs.append(got.get(timeout=1))
                    if msgs[-1][0] == "cutwatch/m1/drive":
                        have += decode_drive(msgs[-1][1]).n
            while time.monotonic() < deadline + 10:
                try:
                    msgs.append(got.get(timeout=1))
                except queue.Empty:
                    break
        finally:
            c.loop_stop()
            c.disconnect()
    meta = [decode_meta(p) for t, p, _ in msgs if t == "cutwatch/m1/meta"]
    blocks = [decode_drive(p) for t, p, _ in msgs if t == "cutwatch/m1/drive"]
    ref = load_log(log)
    assert meta and meta[0]["kind"] == "two_inertia" and meta[0]["nominal"] == ref.nominal
    assert [b.seq for b in blocks] == list(range(len(blocks)))
    n = sum(b.n for b in blocks)
    assert n == ref.n
    for k in ("q_m", "q_l"):
        np.testing.assert_array_equal(np.concatenate([b.columns[k] for b in blocks]), ref[k])
    tau = np.concatenate([b.columns["tau_m"] for b in blocks])
    np.testing.assert_array_equal(tau, ref["tau_m"].astype(np.float32))
    t = np.concatenate([b.t for b in blocks])
    np.testing.assert_allclose(t, ref["t"] - ref["t"][0], atol=1e-9)


def collect(got: queue.Queue, enough: Callable[[list], bool]) -> list[tuple[str, bytes, bool]]:
    """What a subscriber got: until ``enough(msgs)`` (within 60 s: a loaded box can pause
    a stream for over a second, which a wait for the first 1 s pause took for its end),
    then until a 1 s pause (nothing more may follow)."""
    msgs: list[tuple[str, bytes, bool]] = []
    deadline = time.monotonic() + 60
    while not enough(msgs) and time.monotonic() < deadline:
        with contextlib.suppress(queue.Empty):
            msgs.append(got.get(timeout=1))
    while True:
        try:
            msgs.append(got.get(timeout=1))
        except queue.Empty:
            return msgs


def drive_samples(msgs: list[tuple[str, bytes, bool]]) -> int:
    """Samples in the drive blocks among ``msgs``."""
    return sum(decode_drive(p).n for t, p, _ in msgs if t.endswith("/drive"))


def _fed(port: int, argv: list[str], machine: str, samples: int) -> list[tuple[str, bytes, bool]]:
    """Everything a subscriber to ``machine``'s topics receives from one feed of
    ``samples`` samples."""
    c, got = subscriber(port, [f"cutwatch/{machine}/#"])
    try:
        assert main(["feed", *argv, "--broker", f"mqtt://127.0.0.1:{port}",
                     "--machine", machine, "--speed", "0", "--quiet"]) == 0  # fmt: skip
        return collect(got, lambda msgs: drive_samples(msgs) >= samples)
    finally:
        c.loop_stop()
        c.disconnect()


ROOT = Path(__file__).resolve().parents[2]
CNC = ROOT.parent / "shared" / "data" / "cnc-mill" / "experiment_01.csv"


@pytest.mark.skipif(not CNC.exists(), reason="the cnc-mill data set is not present")
def test_a_real_cnc_export_is_fed_as_one_machine_with_every_column_and_its_line() -> None:
    """experiment_01 at 10 Hz: X, Y, Z, the spindle, the program and the G-code line."""
    from common.machine_description import from_dict
    from server.records.drive_wire import check_block, machine_of
    from server.records.measured_log import load_meta

    desc = ROOT / "docs" / "machines" / "cnc-mill.json"
    with broker() as port:
        msgs = _fed(port, [str(CNC), "--meta", str(desc)], "mill", 1055)
    meta = [decode_meta(p) for t, p, _ in msgs if t.endswith("/meta")]
    machine = machine_of(meta[0])
    assert machine == from_dict({**load_meta(desc), "sample_time": 0.1})
    blocks = [decode_drive(p) for t, p, _ in msgs if t.endswith("/drive")]
    ref = load_log(CNC, meta=load_meta(desc))
    assert sum(b.n for b in blocks) == ref.n == 1055
    for b in blocks[:50]:  # every block passes the receiver's check, nothing ignored
        assert check_block(b, machine).ignored == ()
    assert len(blocks[0].columns) == 3 * 7 + 4  # 7 signals per axis, 4 of the spindle
    x = np.concatenate([b.columns["X_q"] for b in blocks])
    np.testing.assert_array_equal(x, ref["X_q"])  # positions travel as float64
    line = np.concatenate([b.identities()["line"] for b in blocks])  # type: ignore[index]
    np.testing.assert_array_equal(line, ref["M1_sequence_number"])
    assert {b.program for b in blocks} == {"1"}


def test_a_log_with_velocity_and_identities_sends_them(tmp_path: Path) -> None:
    from server.records.measured_log import write_log

    n = 300
    t = np.arange(n) * 1e-3
    p = tmp_path / "axis.csv"
    write_log(
        p,
        {
            "t": t,
            "tau_m": np.sin(t),
            "q_m": t * 0.01,
            "qd_m": np.full(n, 0.01),
            "tool": np.where(t < 0.1, 3.0, 4.0),
            "line": 10 + (t // 0.05),
            "override": np.full(n, 0.9),
        },
        {"units": {"effort": "N", "position": "m"}, "kind": "rigid", "program": "O42"},
    )
    with broker() as port:
        msgs = _fed(port, [str(p), "--block-ms", "20"], "ax", n)
    blocks = [decode_drive(p) for t, p, _ in msgs if t.endswith("/drive")]
    assert all(set(b.columns) == {"tau_m", "q_m", "qd_m"} for b in blocks)
    ident = [b.identities() for b in blocks]
    tool = np.concatenate([i["tool"] for i in ident])  # type: ignore[index]
    line = np.concatenate([i["line"] for i in ident])  # type: ignore[index]
    np.testing.assert_array_equal(tool, np.where(t < 0.1, 3, 4))
    np.testing.assert_array_equal(line, 10 + (t // 0.05))
    assert {b.program for b in blocks} == {"O42"} and blocks[0].segments[0].override == 0.9


def test_feed_paces_at_real_time(log: Path) -> None:
    with broker() as port:
        t0 = time.monotonic()
        rc = main(
            ["feed", str(log), "--broker", f"mqtt://127.0.0.1:{port}", "--machine", "m1",
             "--speed", "4", "--quiet"]
        )  # fmt: skip
        took = time.monotonic() - t0
    assert rc == 0
    assert took >= 2 / 4 * 0.95  # a 2 s log at 4x cannot finish sooner than 0.5 s


def test_meta_is_retained_for_a_late_subscriber(log: Path) -> None:
    with broker() as port:
        argv = ["feed", str(log), "--broker", f"mqtt://127.0.0.1:{port}", "--machine", "m2"]
        assert main([*argv, "--speed", "0", "--quiet"]) == 0
        c, got = subscriber(port, ["cutwatch/m2/meta"])
        try:
            topic, payload, retained = got.get(timeout=5)
        finally:
            c.loop_stop()
            c.disconnect()
    assert topic == "cutwatch/m2/meta" and retained and decode_meta(payload)["sample_time"] > 0


def test_wrong_password_and_no_broker_are_clear_errors(
    log: Path, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    with broker(users={"edge": "right"}) as port:
        monkeypatch.setenv("CUTWATCH_MQTT_PASSWORD", "wrong")
        rc = main(
            ["feed", str(log), "--broker", f"mqtt://127.0.0.1:{port}", "--machine", "m1",
             "--username", "edge", "--quiet"]
        )  # fmt: skip
        assert rc == 2
        err = capsys.readouterr().err
        assert "connection refused" in err and "edge@127.0.0.1" in err and "wrong" not in err
        monkeypatch.setenv("CUTWATCH_MQTT_PASSWORD", "right")
        rc = main(
            ["feed", str(log), "--broker", f"mqtt://127.0.0.1:{port}", "--machine", "m1",
             "--username", "edge", "--speed", "0", "--quiet"]
        )  # fmt: skip
        assert rc == 0
    port = port  # the broker is stopped now: nothing listens
    rc = main(["feed", str(log), "--broker", f"mqtt://127.0.0.1:{port}", "--machine", "m1"])
    assert rc == 2
    assert "cannot connect" in capsys.readouterr().err


@pytest.mark.parametrize(
    ("argv", "match"),
    [
        (["--broker", "http://x", "--machine", "m"], "expected mqtt://host"),
        (["--broker", "mqtt://127.0.0.1:1", "--machine", "a/b"], "machine name 'a/b'"),
        (["--broker", "mqtt://127.0.0.1:1", "--machine", "m", "--speed", "-1"], "--speed"),
    ],
)
def test_bad_options_name_the_field(
    log: Path, argv: list[str], match: str, capsys: pytest.CaptureFixture[str]
) -> None:
    assert main(["feed", str(log), *argv]) == 2
    assert match in capsys.readouterr().err


def test_help_explains() -> None:
    out = subprocess.run(
        [sys.executable, "-m", "server.cli.main", "feed", "--help"],
        capture_output=True,
        text=True,
        check=True,
    ).stdout
    assert "cutwatch/<machine>/drive" in out and "--speed" in out
