"""Measurement sources: the simulator and a log replay behind one interface; the pipeline
on a log equals the simulator run that wrote it; a discontinuity resets the observers; a
block of no samples changes nothing (pipeline and live loop)."""

from __future__ import annotations

import time
from dataclasses import fields
from pathlib import Path

import numpy as np
import pytest
from _wait import poll

from estimators.observer_effects import ObserverEffect
from estimators.segment_id import SEG_DISTURBANCE
from machine.stage import SEED000_FORCE, StageConfig
from machine.stage_params import preset
from server.pipeline.live_pipeline import LivePipeline
from server.pipeline.sources import (
    RESUMED,
    MeasurementSource,
    ReplaySource,
    SimulatorSource,
    SourceBlock,
    open_replay,
)
from server.records.measured_log import write_log
from server.service.hub import Hub
from server.service.loop import LiveLoop
from server.service.settings import Settings

N_LOG = 10000  # 4 s at 0.4 ms
BLOCK = 125
#: the plain seed-000 stage: what LivePipeline("seed000-weight") simulates before 10 s
CONFIG = StageConfig(params=preset("seed000"), force=SEED000_FORCE)
MEMBERS = (
    "name kind sample_time nominal encoder_resolution has_truth knobs_apply t finished "
    "step reconfigure reset truth_summary status state restore"
).split()


def write_sim_log(path: Path, start: int = 0, stop: int = N_LOG) -> Path:
    """Simulate CONFIG (seed 0) and write samples [start, stop) as a measured log, in the
    format of ``cutwatch simulate``."""
    src = SimulatorSource(CONFIG, seed=0)
    b = src.step(stop)
    m = b.meas
    cols = {k: getattr(m, k)[start:stop] for k in ("t", "tau_m", "i_m", "q_m", "q_l", "f_ext")}
    side = {
        "sample_time": CONFIG.sample_time,
        "units": {"effort": "N m", "position": "rad", "current": "A"},
        "kind": "two_inertia",
        "nominal": CONFIG.params.as_dict(),
        "encoder_resolution": CONFIG.encoder_resolution,
    }
    write_log(path, cols, side)
    return path


@pytest.fixture(scope="module")
def logs(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    d = tmp_path_factory.mktemp("sources")
    return {
        "full": write_sim_log(d / "full.csv"),
        # the samples after a gap [4000, 5000): what a fresh pipeline sees
        "tail": write_sim_log(d / "tail.csv", start=5000),
    }


def run(p: LivePipeline, n: int = BLOCK) -> dict[str, np.ndarray]:
    """Step ``p`` until its source is finished (or N_LOG samples); concatenated outputs."""
    outs = []
    while not p.finished and p.t < (N_LOG - 0.5) * p.sample_time:
        outs.append(p.step(n))
    return {k: np.concatenate([o[k] for o in outs]) for k in outs[0]}


def use(src: MeasurementSource, n: int) -> SourceBlock:
    """A function typed on the interface: both sources are accepted by mypy."""
    return src.step(n)


# ------------------------------------------------------------------ the interface
def test_both_sources_satisfy_the_interface(logs: dict[str, Path]) -> None:
    sim = SimulatorSource(CONFIG, seed=0)
    rep = ReplaySource(open_replay(logs["full"]))
    for src in (sim, rep):
        assert isinstance(src, MeasurementSource)
        assert all(hasattr(src, m) for m in MEMBERS)
        assert src.kind == "two_inertia" and src.sample_time == pytest.approx(4e-4)
        assert src.nominal.J_L == CONFIG.params.J_L
        assert src.encoder_resolution == CONFIG.encoder_resolution
        assert src.t == 0.0 and not src.finished
        b = use(src, 300)
        assert b.n == 300 and b.discontinuity is None
        assert src.t == pytest.approx(300 * src.sample_time)
    assert sim.has_truth and sim.knobs_apply and sim.name == "simulator"
    assert not rep.has_truth and not rep.knobs_apply and rep.name == "replay"
    # the log hands out exactly the simulated measurements
    sim.reset()
    rep.reset()
    a, b = sim.step(N_LOG), rep.step(N_LOG + 7)  # more than the log has: fewer come
    assert a.truth is not None and b.truth is None
    assert b.n == N_LOG and rep.finished
    for f in fields(a.meas):
        if f.name != "t":
            np.testing.assert_array_equal(getattr(b.meas, f.name), getattr(a.meas, f.name))
    # a log's sample time is the median interval of its t column as read back: 4e-4 to
    # 1.1e-13 relative (the replay counts time from its first sample in that step)
    np.testing.assert_allclose(b.meas.t, a.meas.t, rtol=1e-12, atol=1e-15)
    # after its end a log gives nothing and time stands
    t_end = rep.t
    assert rep.step(BLOCK).n == 0 and rep.t == t_end
    assert rep.status() == {"path": str(logs["full"]), "samples": N_LOG, "fed": N_LOG,
                            "finished": True}  # fmt: skip
    # knobs do not change a log; they change the simulation
    rep.reset()
    first = rep.step(BLOCK).meas.q_m.copy()
    rep.reset()
    rep.reconfigure(extra_inertia=1e-3)
    np.testing.assert_array_equal(rep.step(BLOCK).meas.q_m, first)
    sim.reset()
    sim.reconfigure(extra_inertia=1e-3)
    blk = sim.step(BLOCK)
    assert blk.truth is not None and blk.truth.J_L[0] == pytest.approx(CONFIG.params.J_L + 1e-3)
    assert sim.truth_summary()["J_L"] == pytest.approx(CONFIG.params.J_L + 1e-3)
    sim.reset()  # back to the first configuration
    assert sim.truth_summary()["J_L"] == CONFIG.params.J_L and sim.t == 0.0


# ------------------------------------------------------------------ replay == simulation
def test_replay_through_the_pipeline_equals_the_simulator_run(logs: dict[str, Path]) -> None:
    sim = run(LivePipeline("seed000-weight", seed=0))  # the weight comes at 10 s: after
    rep_pipe = LivePipeline.from_log(logs["full"])
    rep = run(rep_pipe)
    assert rep_pipe.scenario == "replay" and rep_pipe.finished
    assert len(rep["t"]) == N_LOG
    estimates = [
        "t", "f_fixed", "f_adaptive", "f_switching", "J_L_adaptive", "J_L_switching",
        "B_L_adaptive", "B_L_switching", "F_CL_adaptive", "F_CL_switching", "f_effects",
        "f_dfo", "h1_amp", "h2_amp", "mode_switching", "excitation", "q_m", "x_l",
        "f_true",  # the log's f_ext, the simulated force
    ]  # fmt: skip
    # the replay's sample time is the log's median interval, 1.1e-13 relative from the
    # simulator's 4e-4 (see above): equal to that rounding, not bit for bit (measured: at
    # most 3.4e-11 of each channel's largest value; the measurements themselves exact)
    for k in estimates:
        err = float(np.max(np.abs(rep[k] - sim[k])))
        assert err <= 1e-9 * float(np.max(np.abs(sim[k]))), (k, err)
    for k in ("q_m", "x_l", "f_true", "mode_switching"):
        np.testing.assert_array_equal(rep[k], sim[k], err_msg=k)
    # the simulator-only truth is unknown in the replay; the wear is the default scenario's
    for k in ("J_L_true", "omega_l", "h1_true"):
        assert np.all(np.isnan(rep[k])) and np.all(np.isfinite(sim[k])), k
    assert "vb_true" not in rep and "vb_true" not in sim
    snap = rep_pipe.snapshot()
    assert snap["truth"] == {"log": str(logs["full"]), "samples": N_LOG}
    assert snap["replay"] == {"path": str(logs["full"]), "samples": N_LOG, "fed": N_LOG,
                              "finished": True}  # fmt: skip
    rep_pipe.reset()  # a replay starts again from its first sample
    assert rep_pipe.t == 0.0 and not rep_pipe.finished
    np.testing.assert_array_equal(rep_pipe.step(BLOCK)["f_adaptive"], rep["f_adaptive"][:BLOCK])


# ------------------------------------------------------------------ discontinuity
class GappySource(ReplaySource):
    """A log with samples [gap_from, gap_to) lost, as a live feed loses a block; the first
    block after the loss says so when ``mark`` is true. Every other call gives nothing
    when ``stutter`` is true (a feed with no new data yet)."""

    def __init__(self, path: Path, gap_from: int, gap_to: int, *, mark: bool = True,
                 stutter: bool = False) -> None:  # fmt: skip
        super().__init__(open_replay(path))
        self.gap = (gap_from, gap_to)
        self.mark = mark
        self.stutter = stutter
        self.calls = 0

    def step(self, n: int) -> SourceBlock:
        self.calls += 1
        if self.stutter and self.calls % 2 == 0:
            return super().step(0)
        jumped = False
        if self.k == self.gap[0] < self.gap[1]:
            self.k = self.gap[1]  # the lost samples never arrive
            jumped = True
        b = super().step(min(n, self.gap[0] - self.k) if self.k < self.gap[0] else n)
        return SourceBlock(b.meas, None, "gap" if jumped and self.mark else None)


class SilentSource(ReplaySource):
    """A live feed that never delivers: not finished, no samples."""

    calls = 0

    @property
    def finished(self) -> bool:
        return False

    def step(self, n: int) -> SourceBlock:
        self.calls += 1
        return super().step(0)


EFFECT = (ObserverEffect("offset", {}, (0.3,)),)


@pytest.mark.parametrize("mark", [True, False])
def test_a_discontinuity_resets_the_observers(logs: dict[str, Path], mark: bool) -> None:
    gappy = LivePipeline(source=GappySource(logs["full"], 4000, 5000, mark=mark))
    fresh = LivePipeline.from_log(logs["tail"])  # a fresh pipeline on the data after it
    for p in (gappy, fresh):
        p.set_observer_effects(EFFECT)  # the identified effects' state is reset too
    out = run(gappy)
    assert gappy.finished and len(out["t"]) == N_LOG - 1000
    after = {k: v[4000:] for k, v in out.items()}
    ref = run(fresh)
    names = [c.name for c in fresh.channels()]
    same = [k for k in names if np.array_equal(after[k], ref[k], equal_nan=True)]
    if mark:
        assert same == names  # every estimate equals the fresh pipeline's
        np.testing.assert_allclose(after["t"] - ref["t"], 5000 * fresh.sample_time, rtol=1e-9)
    else:  # not marked: the observers bridge the gap and their estimates differ
        for k in ("f_fixed", "f_adaptive", "f_switching", "J_L_adaptive", "f_dfo", "f_effects"):
            assert k not in same, k


# ------------------------------------------------------------------ empty blocks
def test_empty_blocks_change_nothing(logs: dict[str, Path]) -> None:
    src = GappySource(logs["full"], N_LOG, N_LOG, stutter=True)  # no gap; every 2nd empty
    p = LivePipeline(source=src)
    plain = LivePipeline.from_log(logs["full"])
    got: list[dict[str, np.ndarray]] = []
    empties = 0
    while not p.finished:
        t0, last = p.t, p.latest
        o = p.step(BLOCK)
        if len(o["t"]) == 0:
            empties += 1
            assert set(o) == {c.name for c in p.channels()} | {"t"}
            assert all(v.shape == (0,) for v in o.values())
            assert p.t == t0 and p.latest == last  # time and state stand
        else:
            got.append(o)
    assert len(got) == N_LOG // BLOCK and empties == len(got) - 1  # one between blocks
    ref = run(plain)
    for k in ref:
        np.testing.assert_array_equal(np.concatenate([o[k] for o in got]), ref[k], err_msg=k)


@pytest.mark.slow
def test_the_live_loop_waits_on_a_source_with_nothing(logs: dict[str, Path]) -> None:
    src = GappySource(logs["full"], N_LOG, N_LOG, stutter=True)
    loop = LiveLoop(Settings(scenario="default", viser=False), Hub(4))
    loop.start()
    try:
        deadline = time.monotonic() + 30
        while loop.blocks < 2:  # past the warm-up block
            assert time.monotonic() < deadline
            time.sleep(0.02)
        loop.set_pipeline(LivePipeline(source=src))
        loop.set_speed(50.0)
        deadline = time.monotonic() + 60
        while not loop.pipeline.finished:
            assert time.monotonic() < deadline and loop.error is None
            time.sleep(0.05)
        # the loop pauses on its next turn after the source finished: polled (was a
        # fixed 0.3 s, which a loaded box's loop may not have had)
        poll(lambda: loop.paused or loop.error is not None, 30, 0.05)
        assert loop.running and loop.error is None and loop.paused  # ended like a replay
        assert loop.pipeline.t == pytest.approx(N_LOG * 4e-4)
        # a feed that never delivers: the loop stays up, time stands, and it waits a frame
        # period between tries instead of spinning on the lock
        idle = SilentSource(open_replay(logs["full"]))
        loop.set_pipeline(LivePipeline(source=idle))
        loop.set_speed(1.0)
        calls0, t0 = idle.calls, time.monotonic()
        time.sleep(1.0)
        calls = idle.calls - calls0
        dt = time.monotonic() - t0
        assert loop.running and loop.error is None and loop.pipeline.t == 0.0
        assert 1 <= calls <= dt * Settings(viser=False).frame_hz + 5, calls
    finally:
        loop.stop()


class ResumingLog(ReplaySource):
    """A log that, restored from a checkpoint, goes on after a break of ``GAP`` samples
    and marks its next block RESUMED: what a live feed does after the service restarted."""

    GAP = 500

    def restore(self, state: object) -> None:
        super().restore(state)
        self.k += self.GAP
        self._resumed = True

    def step(self, n: int) -> SourceBlock:
        blk = super().step(n)
        if getattr(self, "_resumed", False) and blk.n:
            self._resumed = False
            return SourceBlock(blk.meas, blk.truth, RESUMED)
        return blk


def test_a_feed_resumed_from_a_checkpoint_keeps_its_estimates(logs: dict[str, Path]) -> None:
    a = LivePipeline.from_log(logs["full"])
    for _ in range(40):  # 2 s
        a.step(BLOCK)
    state = a.state()
    kept = state.parts["stage"]
    b = LivePipeline(source=ResumingLog(open_replay(logs["full"])))
    b.restore(state)
    out = b.step(BLOCK)  # the first block after the break
    assert b.t == pytest.approx(a.t + (ResumingLog.GAP + BLOCK) * a.sample_time)
    # the filters restarted (no derivative across the break), the estimates went on
    for k in ("f_fixed", "f_adaptive", "f_segment", "J_L_adaptive"):
        assert np.all(np.isfinite(out[k])), k
    # the first estimate uses the parameters identified before the break, not the
    # nominal ones a restart from scratch would use
    j_nom = CONFIG.params.J_L
    assert abs(a.latest["J_L_adaptive"] - j_nom) > 1e-4 * j_nom
    assert out["J_L_adaptive"][0] == a.latest["J_L_adaptive"]
    # the RLS covariance goes on from the state's (a fresh one starts from p0 I)
    fresh = LivePipeline.from_log(logs["full"])
    fresh.step(BLOCK)
    p_kept, p_b = kept.ident.rls4.P, b.run.s_ident.rls4.P
    p_new = fresh.run.s_ident.rls4.P
    assert np.linalg.norm(p_b - p_kept) < np.linalg.norm(p_new - p_kept)
    # a gap without RESUMED restarts everything (test_a_discontinuity_resets_the_observers)
    assert b.run.s_seg.seg[SEG_DISTURBANCE] == pytest.approx(a.t + ResumingLog.GAP * a.sample_time)
