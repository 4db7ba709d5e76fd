"""The live part protocol: a pipeline loops over its parts, asks each what it needs and asks
again when the machine changes, stops a part that raises (and those that need it) and
goes on, keeps each part's state (never the part), and lists every part with its reason.
"""

from __future__ import annotations

import gzip
import shutil
from pathlib import Path

import numpy as np
import pytest

from common.state_io import read_header
from server.errors import CutwatchError
from server.pipeline.checkpoint import load_checkpoint, save_checkpoint
from server.pipeline.live_pipeline import LivePipeline
from server.pipeline.machine_view import MachineView
from server.pipeline.part import (
    Block,
    Channel,
    LivePart,
    Outputs,
    Setup,
    Verdict,
    needs_band,
)
from server.pipeline.part_registry import load, registered
from server.pipeline.runtime import MachineRuntime

BLOCK = 125
V2 = Path(__file__).parent / "data" / "pipeline-v2-default.npz.gz"


class Breaks(LivePart):
    """Raises in its third block."""

    name = "breaks"
    channels = (Channel("breaks_n", "", "blocks stepped", "toy"),)

    def __init__(self) -> None:
        self.n = 0

    def step(self, block: Block) -> Outputs:
        self.n += 1
        if self.n == 3:
            raise ValueError("a division by the spindle's zero speed")
        return {"breaks_n": block.held(self.n)}, []


class NeedsBreaks(LivePart):
    """Reads what :class:`Breaks` streams."""

    name = "after_breaks"
    needs = ("breaks",)
    channels = (Channel("after_n", "", "twice the blocks", "toy"),)

    def step(self, block: Block) -> Outputs:
        return {"after_n": 2.0 * block.outputs["breaks_n"]}, []


class Pattern(LivePart):
    """A pattern at 30 x the spindle's rotation: it needs that below the Nyquist frequency
    (1250 Hz at 2.5 kHz: spindle speeds up to 2500 rpm)."""

    name = "pattern"
    channels = (Channel("pattern_hz", "Hz", "the pattern's frequency", "toy"),)

    def __init__(self) -> None:
        self.configured: list[float] = []

    def requires(self, machine: MachineView) -> Verdict:
        return needs_band(machine, 30.0 * machine.spindle_rpm / 60.0, "the 30x pattern")

    def configure(self, setup: Setup) -> None:
        self.configured.append(setup.machine.spindle_rpm)

    def step(self, block: Block) -> Outputs:
        return {"pattern_hz": block.held(30.0 * block.machine.spindle_rpm / 60.0)}, []


def test_a_part_that_raises_is_stopped_and_the_others_go_on() -> None:
    with registered(Breaks, NeedsBreaks):
        p = LivePipeline("seed000-weight")
    outs = [p.step(BLOCK) for _ in range(5)]
    st = {s["name"]: s for s in p.parts()}
    assert st["breaks"]["running"] is False
    assert st["breaks"]["reason"] == (
        "stopped: step raised ValueError: a division by the spindle's zero speed"
    )
    why = "stopped: needs the breaks part, which stopped"
    assert st["after_breaks"] == {"name": "after_breaks", "running": False, "reason": why}
    assert all(st[n]["running"] for n in ("stage", "effects", "dfo"))
    # its blocks before the failure streamed, NaN after; the stage's blocks all finite
    assert [o["breaks_n"][-1] for o in outs[:2]] == [1.0, 2.0]
    assert all(np.isnan(o["breaks_n"]).all() and np.isnan(o["after_n"]).all() for o in outs[2:])
    assert all(np.isfinite(o["f_segment"]).all() for o in outs)
    # stopped until a reset, which builds every part again
    p.reset()
    assert all(s["running"] for s in p.parts())


def test_a_part_is_asked_again_when_the_spindle_speed_changes() -> None:
    with registered(Pattern):
        p = LivePipeline("seed000-weight")
    part = p.part("pattern")
    why = "the 30x pattern at 1500 Hz is above the Nyquist frequency 1250 Hz of a 2500 Hz source"
    out = p.step(BLOCK)  # 3000 rpm: 1500 Hz
    assert p.parts()[-1] == {"name": "pattern", "running": False, "reason": why}
    assert np.isnan(out["pattern_hz"]).all() and part.configured == []
    p.set_knob("spindle_rpm", 2400.0)  # 1200 Hz: below 1250, it runs, configured for it
    assert p.step(BLOCK)["pattern_hz"][-1] == 1200.0
    assert p.parts()[-1]["running"] and part.configured == [2400.0]
    p.set_knob("spindle_rpm", 3000.0)  # paused again
    assert np.isnan(p.step(BLOCK)["pattern_hz"]).all() and p.parts()[-1]["reason"] == why
    p.set_knob("spindle_rpm", 1200.0)  # 600 Hz
    assert p.step(BLOCK)["pattern_hz"][-1] == 600.0
    assert p.parts()[-1]["running"] and part.configured == [2400.0, 1200.0]


def test_a_slow_source_gets_a_q_designed_from_its_rate(tmp_path: Path) -> None:
    # a two-inertia log at 417 Hz: seed 000's Q(s) (250 Hz) would lie above its Nyquist
    # frequency (208 Hz); since issue 30 the observer's Q(s) is designed from the rate
    # (q_cutoff: 0.4 of the rate), so the stage and what needs it run. A source the stage
    # cannot watch at all (a rigid axis) is listed, not fatal: the test below.
    from test_sources import CONFIG

    from estimators.force_observer import q_cutoff
    from machine.stage import StageSim
    from server.records.measured_log import write_log

    sim = StageSim(CONFIG, seed=0)
    m, _ = sim.step(5000)
    k = slice(None, None, 6)  # every 6th sample of 2.5 kHz: 417 Hz
    cols = {n: getattr(m, n)[k] for n in ("t", "tau_m", "i_m", "q_m", "q_l", "f_ext")}
    side = {
        "sample_time": CONFIG.sample_time * 6,
        "units": {"effort": "N m", "position": "rad", "current": "A"},
        "kind": "two_inertia",
        "nominal": CONFIG.params.as_dict(),
        "encoder_resolution": CONFIG.encoder_resolution,
    }
    write_log(tmp_path / "slow.csv", cols, side)
    p = LivePipeline.from_log(tmp_path / "slow.csv")
    st = {s["name"]: s for s in p.parts()}
    assert st["stage"]["running"] and st["dfo"]["running"], st
    q_hz = q_cutoff(CONFIG.sample_time * 6)
    assert q_hz < 0.5 / (CONFIG.sample_time * 6) and q_hz < 250.0
    out = p.step(200)
    assert out["t"].size == 200 and np.isfinite(out["f_fixed"][-50:]).all()


def test_the_state_holds_each_parts_state_never_a_part(tmp_path: Path) -> None:
    p = LivePipeline("default")
    for _ in range(20):
        p.step(BLOCK)
    path = tmp_path / "state.npz"
    save_checkpoint(path, p.state())
    names: list[str] = []

    def walk(node: object) -> None:
        if isinstance(node, dict):
            if "obj" in node:
                names.append(str(node["obj"]))
            for v in node.values():
                walk(v)
        elif isinstance(node, list):
            for v in node:
                walk(v)

    walk(read_header(path)["tree"])
    import importlib

    classes = []
    for name in names:
        mod, _, qual = name.partition(":")
        classes.append(getattr(importlib.import_module(mod), qual))
    assert not [c for c in classes if issubclass(c, LivePart)]
    state = load_checkpoint(path)
    assert sorted(state.parts) == sorted(s["name"] for s in p.parts())
    assert type(state.parts["eccentricity"]).__name__ == "EccentricityState"


def test_a_checkpoint_of_version_2_is_refused_by_its_version_and_the_runtime_starts_fresh(
    tmp_path: Path,
) -> None:
    # written by the code before the parts (its eccentricity part was the object itself)
    path = tmp_path / "pipeline.npz"
    with gzip.open(V2) as src, path.open("wb") as dst:
        shutil.copyfileobj(src, dst)
    assert read_header(path)["version"] == 2
    rt = MachineRuntime("m", LivePipeline("default"), checkpoint=path)
    assert rt.resume() is False
    refused = rt.checkpoint_status["refused"]
    assert refused == f"{path}: expected cutwatch.pipeline version 3, found 2"
    out, _ = rt.step(BLOCK)
    assert out["t"][0] == pytest.approx(-rt.pipeline.sample_time)  # fresh: from t = 0
    assert rt.save() and read_header(path)["version"] == 3  # the next checkpoint replaces it


def test_a_part_named_by_module_and_attribute() -> None:
    f = load("test_parts:Pattern")
    assert callable(f)
    for spec, msg in (
        ("nomodule", "expected module:attribute"),
        ("no_such_module_here:X", "module 'no_such_module_here' not importable"),
        ("test_parts:Nope", "module 'test_parts' has no attribute 'Nope'"),
        ("test_parts:BLOCK", "expected a part class or factory, found int"),
    ):
        with pytest.raises(CutwatchError, match=msg):
            load(spec)


def test_the_machine_view_is_read_from_the_feeds_description() -> None:
    # a rigid axis and a spindle, as a broker meta describes them (issue 30's schema): the
    # stage's observers need a two-inertia axis and say so, naming what the machine has
    from server.pipeline.broker import parse_broker_url
    from server.pipeline.drive_feed import DriveFeed
    from server.pipeline.mqtt_source import MqttSource
    from server.records.drive_wire import encode_meta

    desc = {
        "sample_time": 0.001,
        "axes": {"X": {"kind": "rigid", "signals": {"q_m": "x_pos", "i_m": "x_cur"},
                       "units": {"position": "m"}}},
        "spindle": {"signals": {"speed": "s_rpm", "power": "s_pow"}},
        "identities": {"tool": "tool", "line": "line"},
    }  # fmt: skip
    feed = DriveFeed(parse_broker_url("mqtt://127.0.0.1:1"), "lathe")
    feed.push_meta(encode_meta(desc))
    view = MachineView.of(MqttSource(feed), 1200.0)
    assert [(a.name, a.kind, sorted(a.roles)) for a in view.axes] == [
        ("X", "rigid", ["i_m", "q_m"])
    ]
    assert view.spindle == {"speed", "power"} and view.identities == {"tool", "line"}
    assert view.signals >= {"q_m", "i_m", "spindle.speed", "spindle.power", "tool"}
    p = LivePipeline(source=MqttSource(feed))
    st = {s["name"]: s for s in p.parts()}
    assert st["stage"] == {
        "name": "stage",
        "running": False,
        "reason": "needs a two_inertia axis with q_m, q_l and tau_m or i_m (seed 000's "
        "shaft-twist branch); the mqtt source's machine has X (rigid: i_m, q_m)",
    }
    assert st["dfo"]["reason"].startswith("needs the stage part, which does not run")


class NoBuild(LivePart):
    """Cannot even be built here."""

    name = "no_build"

    def __init__(self) -> None:
        raise RuntimeError("its filter needs 10 kHz")


def test_a_part_that_cannot_be_built_is_listed_by_its_name() -> None:
    with registered(NoBuild):
        p = LivePipeline("seed000-weight")
    why = "not built: RuntimeError: its filter needs 10 kHz"
    assert p.parts()[-1] == {"name": "no_build", "running": False, "reason": why}
    assert np.isfinite(p.step(BLOCK)["f_segment"]).all()
