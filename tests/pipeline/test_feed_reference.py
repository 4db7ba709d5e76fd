"""Issue 30, item 6, on a feed: the measured force is the accuracy panel's reference when
the machine has one (else the panel says there is none and ranks nothing), and the
spindle's speed signal is the spindle speed in effect, which the DFO follows.

A simulated two-inertia axis described as a CNC's feed (minor 2: its own column names, a
spindle speed signal), its drive blocks pushed into a real DriveFeed and read by the
MqttSource, as the service does (the broker itself: tests/service/test_mqtt_service.py).
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from test_sources import CONFIG

from common.errors import ParameterError
from machine.stage import StageSim
from server.pipeline.broker import parse_broker_url
from server.pipeline.drive_feed import DriveFeed
from server.pipeline.knobs import BASE_RPM
from server.pipeline.live_pipeline import LivePipeline
from server.pipeline.mqtt_source import MqttSource
from server.records.drive_wire import encode_drive, encode_meta

TS = CONFIG.sample_time
N = 125  # samples per drive block (50 ms)
NOMINAL = {k: v for k, v in CONFIG.params.as_dict().items() if k not in ("K_t", "C_s")}


def machine(f_ext: bool, spindle: bool) -> dict[str, object]:
    sig = {"q_m": "X_enc", "q_l": "X_scale", "tau_m": "X_torque"}
    if f_ext:
        sig["f_ext"] = "X_dyn"
    d: dict[str, object] = {
        "sample_time": TS,
        "axes": {
            "X": {
                "kind": "two_inertia",
                "signals": sig,
                "units": {"position": "rad", "effort": "N m"},
                "K_t": CONFIG.params.K_t,
                "nominal": NOMINAL,
                "encoder_resolution": CONFIG.encoder_resolution,
            }
        },
    }
    if spindle:
        d["spindle"] = {"signals": {"speed": "S_speed"}, "units": {"speed": "rpm"}}
    return d


UNITS = {"X_enc": "rad", "X_scale": "rad", "X_torque": "N m", "X_dyn": "N m", "S_speed": "rpm"}


def feed_of(
    blocks: int, f_ext: bool = True, rpm: list[float] | None = None
) -> tuple[DriveFeed, list[np.ndarray]]:
    """A feed holding ``blocks`` simulated drive blocks; ``rpm``: the spindle's speed per
    block (None: no spindle signal). Returns the feed and the measured force per block."""
    feed = DriveFeed(parse_broker_url("mqtt://127.0.0.1:1"), "m1", max_samples=(blocks + 1) * N)
    feed.push_meta(encode_meta(machine(f_ext, rpm is not None)))
    sim = StageSim(CONFIG, seed=3)
    forces = []
    for b in range(blocks):
        m, _ = sim.step(N)
        cols = {"X_enc": m.q_m, "X_scale": m.q_l, "X_torque": m.tau_m}
        if f_ext:
            cols["X_dyn"] = m.f_ext
        if rpm is not None:
            cols["S_speed"] = np.full(N, rpm[b]) + np.sin(np.arange(N))  # a CNC's jitter
        feed.push(encode_drive(b, b * N * TS, TS, cols, {k: UNITS[k] for k in cols}))
        forces.append(np.asarray(m.f_ext))
    return feed, forces


def test_the_measured_force_is_the_reference() -> None:
    feed, sent = feed_of(40)
    p = LivePipeline(source=MqttSource(feed))
    assert {s["name"]: s["running"] for s in p.parts()}["stage"], p.parts()
    outs, forces = [], []
    for _ in range(40):
        outs.append(p.step(N))
        assert p.last_block is not None
        forces.append(p.last_block.meas.f_ext)  # as the wire carried it (float32)
    np.testing.assert_allclose(np.concatenate(forces), np.concatenate(sent), rtol=1e-6, atol=1e-6)
    acc = p.accuracy()
    assert acc["mode"] == "measured_force" and acc["against"] == "measured_force"
    assert acc["reason"] == "" and acc["rms_q"] == {}
    # the last 1 s (20 blocks): each estimate against the force the feed measured
    f = np.concatenate(forces[-20:])
    for k in ("f_fixed", "f_adaptive", "f_segment", "f_dfo"):
        e = np.concatenate([o[k] for o in outs[-20:]])
        want = float(np.sqrt(np.mean((e - f) ** 2)))
        assert acc["rms"][k][0] == pytest.approx(want, rel=1e-9), k  # type: ignore[index]
    # the scores mean something against a real reference: the DFO, which models the
    # tooth-passing harmonics, is far closer to it than the Q(s)-limited fixed observer
    # and than no estimate at all
    rms = {k: v[0] for k, v in acc["rms"].items()}  # type: ignore[attr-defined]
    assert rms["f_dfo"] < 0.5 * rms["f_fixed"] and rms["f_dfo"] < 0.5 * float(
        np.sqrt(np.mean(f**2))
    )


def test_without_a_measured_force_nothing_is_ranked() -> None:
    feed, _ = feed_of(10, f_ext=False)
    p = LivePipeline(source=MqttSource(feed))
    for _ in range(10):
        p.step(N)
    acc = p.accuracy()
    assert acc["mode"] == "none" and acc["against"] is None
    assert "no reference" in str(acc["reason"])
    assert all(math.isnan(v) for r in acc["rms"].values() for v in r)  # type: ignore[attr-defined]


def test_the_dfo_follows_the_spindle_speed_the_feed_sends() -> None:
    rpm = [2400.0] * 10 + [3600.0] * 10
    feed, _ = feed_of(20, rpm=rpm)
    p = LivePipeline(source=MqttSource(feed))
    # the knob does not drive a real machine's spindle: a feed's pipeline does not offer it
    assert "spindle_rpm" not in p.knobs()
    with pytest.raises(ParameterError, match=r"spindle_rpm.*simulated stage"):
        p.set_knob("spindle_rpm", 3000.0)
    dfo = p.part("dfo")
    base = np.array(dfo.base)
    seen = []
    for _ in range(20):
        out = p.step(N)
        seen.append((out["spindle_rpm"][-1], tuple(dfo.dfo.params.frequencies)))
    # the jitter (+-1 rpm) does not retune it; a real step does, at the block it arrives
    for part, want in ((seen[:10], 2400.0), (seen[10:], 3600.0)):
        held = {r for r, _ in part}
        assert len(held) == 1 and abs(held.pop() - want) <= 1.0, part
    for r, freqs in seen:
        np.testing.assert_allclose(freqs, base * r / BASE_RPM)
    assert {s["name"]: s["running"] for s in p.parts()}["dfo"]
