"""The process monitor in the live pipeline (server/pipeline/process_part.py).

The default scenario cuts the default part program beside the stage; events are injected
through ``LivePipeline.inject`` and found by the monitor on the drives' force estimate.
Delays are measured from each event's truth (its first sample), sample-exact, on the
machine's own 5 kHz samples (``LiveProcess.fine``). A pipeline is taught once per seed
(``teach_parts`` 2) and copied for each case.
"""

from __future__ import annotations

import copy
import math
from pathlib import Path

import numpy as np
import pytest

from common.errors import ParameterError
from machine.process import EVENT_KINDS
from server.pipeline.checkpoint import load_checkpoint, save_checkpoint
from server.pipeline.live_pipeline import LivePipeline
from server.pipeline.process_part import LiveProcess

BLOCK = 125  # 50 ms of the stage at 2.5 kHz, the live block
SEEDS = (0, 1, 2, 3)
TEACH = 2


def _process_events(p: LivePipeline) -> list:  # type: ignore[type-arg]
    """The process monitor's events taken from the pipeline (the stage's wear alarms,
    another detector's, are left out: their tests are in tests/pipeline/test_wear_alarms.py)."""
    return [e for e in p.take_events() if e.kind in EVENT_KINDS]


def _proc(p: LivePipeline) -> LiveProcess:
    part = p.part("process")
    assert part is not None
    return part.live  # type: ignore[no-any-return]


def _taught(seed: int) -> LivePipeline:
    """A default pipeline whose monitor watches every block of the program."""
    p = LivePipeline("default", seed=seed)
    p.set_knob("teach_parts", TEACH)
    st = _proc(p).taught
    while True:
        p.step(BLOCK)
        used = st["key_tool"] >= 0
        if used.sum() == 7 and np.all(st["parts"][used] >= TEACH):
            break
        assert p.t < 200.0, "teach-in did not end"
    assert _process_events(p) == []
    return p


@pytest.fixture(scope="module")
def taught() -> dict[int, LivePipeline]:
    return {s: _taught(s) for s in SEEDS}


def _run(p: LivePipeline, until: float) -> tuple[dict[str, np.ndarray], list]:  # type: ignore[type-arg]
    """Step until ``until`` [s]; the 5 kHz columns of every step and the events."""
    fine: list[dict[str, np.ndarray]] = []
    events = []
    while p.t < until:
        p.step(BLOCK)
        fine.append(_proc(p).fine)
        events += _process_events(p)
    cols = {k: np.concatenate([f[k] for f in fine]) for k in fine[0]}
    return cols, events


def _past_event(p: LivePipeline, extra: float) -> tuple[dict[str, np.ndarray], list, dict]:  # type: ignore[type-arg]
    """Step until the next injected event has happened and ``extra`` [s] more; the 5 kHz
    columns and the events from now on, and the event's truth."""
    n0 = len(p.process_truths())
    fine: list[dict[str, np.ndarray]] = []
    events = []
    while len(p.process_truths()) == n0 or p.t < float(p.process_truths()[n0]["t"]) + extra:
        p.step(BLOCK)
        fine.append(_proc(p).fine)
        events += _process_events(p)
        assert p.t < 1000.0
    cols = {k: np.concatenate([f[k] for f in fine]) for k in fine[0]}
    return cols, events, p.process_truths()[n0]


def _until_line(p: LivePipeline, line: int) -> None:
    """Step until the block of ``line`` has just started."""
    proc = _proc(p)
    while True:
        p.step(BLOCK)
        run = proc.ps.run
        if run is not None and run.blk.line == line and run.done < 3 * BLOCK:
            return
        assert p.t < 500.0


def _inject_mid_cut(p: LivePipeline, kind: str, line: int, frac: float) -> dict[str, object]:
    """Inject ``kind`` at ``frac`` of the next execution of cut block ``line``."""
    _until_line(p, line)
    run = _proc(p).ps.run
    assert run is not None and run.blk.cut
    ts = _proc(p).sample_time
    at = (run.k_start + frac * run.n_total) * ts
    return p.inject(kind, at_t=at)


RPM = {20: 1200.0, 40: 1500.0, 60: 1800.0}


@pytest.mark.parametrize("seed", SEEDS)
def test_a_breakage_is_found_within_two_revolutions(taught, seed: int) -> None:  # type: ignore[no-untyped-def]
    p = copy.deepcopy(taught[seed])
    rng = np.random.default_rng(seed)
    for line in (20, 40, 60):
        # one breakage per part (the broken tool is changed at the end of the part)
        _until_line(p, 10)
        _inject_mid_cut(p, "breakage", line, float(rng.uniform(0.35, 0.65)))
        _, events, truth = _past_event(p, 1.0)
        assert truth["kind"] == "breakage" and truth["line"] == line
        found = [e for e in events if e.kind == "breakage" and e.t >= truth["t"]]
        assert found, (line, events)
        # nothing before the event's first sample
        assert all(e.t >= truth["t"] for e in events)
        delay = found[0].t - float(truth["t"])
        assert 0.0 <= delay <= 2 * 60.0 / RPM[line], (line, delay)
        ev = found[0]
        assert (ev.tool, ev.line, ev.program, ev.part) == (
            truth["tool"],
            line,
            "O1001",
            truth["part"],
        )
        assert ev.action == "feed_hold" and ev.value > ev.limit and ev.message


@pytest.mark.parametrize("seed", SEEDS)
def test_a_collision_is_found_within_5_ms_of_the_estimate_crossing_its_limit(  # type: ignore[no-untyped-def]
    taught, seed: int
) -> None:
    p = copy.deepcopy(taught[seed])
    _inject_mid_cut(p, "collision", 40, 0.5)
    cols, events, truth = _past_event(p, 0.5)
    found = [e for e in events if e.kind == "collision"]
    assert found, events
    t = cols["t"]
    after = (t >= truth["t"]) & (cols["mon_f"] > cols["mon_extreme"])
    t_cross = float(t[np.flatnonzero(after)[0]])
    assert 0.0 <= found[0].t - t_cross <= 5e-3
    assert found[0].t >= truth["t"] and found[0].unit == "N"


@pytest.mark.parametrize("seed", SEEDS)
def test_a_missing_tool_is_found_within_its_block(taught, seed: int) -> None:  # type: ignore[no-untyped-def]
    p = copy.deepcopy(taught[seed])
    part = int(p.monitor_status()["part"]) + 1  # type: ignore[call-overload]
    got = p.inject("missing_tool", at_part=part)
    assert got["at_part"] == part and got["size"] == 1.0
    while not p.process_truths():
        p.step(BLOCK)
    truth = p.process_truths()[-1]
    run = _proc(p).ps.run
    assert run is not None
    block_s = run.n_total * _proc(p).sample_time
    _, events = _run(p, float(truth["t"]) + block_s)
    found = [e for e in events if e.kind == "missing_tool"]
    assert found and found[0].line == truth["line"] == 20
    assert 0.0 <= found[0].t - float(truth["t"]) <= block_s


def test_good_parts_raise_no_event_and_stream_their_limits(taught) -> None:  # type: ignore[no-untyped-def]
    parts = 0
    for seed in SEEDS:
        p = copy.deepcopy(taught[seed])
        first = int(p.monitor_status()["part"])  # type: ignore[call-overload]
        _, events = _run(p, p.t + 60.0)
        assert events == [], seed
        parts += int(p.monitor_status()["part"]) - first  # type: ignore[call-overload]
        out = p.step(BLOCK)
        assert set(out) >= {"mon_f", "mon_mean", "mon_upper", "mon_lower", "mon_extreme",
                            "mon_state", "mon_tool", "mon_line"}  # fmt: skip
        assert np.all(out["mon_state"] == 1.0)
        assert np.isfinite(out["mon_extreme"]).all()
        assert p.monitor_status()["state"] == "watching"
    assert parts >= 16  # 0 events in >= 16 watched parts (4 seeds x ~60 s)


def test_an_alarm_sets_the_state_and_the_status(taught) -> None:  # type: ignore[no-untyped-def]
    p = copy.deepcopy(taught[0])
    _inject_mid_cut(p, "collision", 20, 0.5)
    seen = False
    while not seen:
        out = p.step(BLOCK)
        if _process_events(p):
            seen = True
            assert out["mon_state"][-1] == 2.0
            assert p.monitor_status()["state"] == "alarm"
            assert p.monitor_status()["line"] == 20
    # the truth beside the measurements: the collision's code from its first sample on
    assert out["mon_event_true"][-1] == 2.0
    assert [t["kind"] for t in p.process_truths()] == ["collision"]


def test_an_injection_now_lands_in_the_middle_of_a_cut_and_is_found(taught) -> None:  # type: ignore[no-untyped-def]
    for line in (10, 20):  # asked in an air move, and at the start of a cut
        p = copy.deepcopy(taught[1])
        _until_line(p, line)
        p.inject("breakage")
        _, events, truth = _past_event(p, 1.0)
        assert truth["line"] == 20
        assert [e.kind for e in events][:1] == ["breakage"]
        assert events[0].t - float(truth["t"]) <= 2 * 60.0 / RPM[20]


def test_a_second_breakage_before_the_tool_change_breaks_another_flute(taught) -> None:  # type: ignore[no-untyped-def]
    p = copy.deepcopy(taught[0])
    for line in (20, 40):  # one part, T1 not changed in between
        _inject_mid_cut(p, "breakage", line, 0.5)
        _, events, truth = _past_event(p, 1.0)
        assert truth["line"] == line
        assert "breakage" in [e.kind for e in events]
    _until_line(p, 50)  # N40 closed, the part not yet over: T1 not yet changed
    assert (_proc(p).ps.machine.instances[1].dr[:4] < 0).sum() == 2


def test_a_broken_tool_is_changed_after_its_alarm(taught) -> None:  # type: ignore[no-untyped-def]
    p = copy.deepcopy(taught[2])
    proc = _proc(p)
    assert proc.take_tool_changes() == []
    _inject_mid_cut(p, "breakage", 40, 0.5)
    _, events, _ = _past_event(p, 1.0)
    assert [e.kind for e in events][:1] == ["breakage"]
    _until_line(p, 10)  # the next part: T1 changed by the operator
    (ch,) = proc.take_tool_changes()
    assert ch["tool"] == 1 and ch["cause"] == "breakage"
    assert ch["start_t"] == 0.0 and ch["end_t"] == pytest.approx(p.t, abs=0.1)
    assert not proc.ps.machine.instances[1].dr.any()  # whole flutes again
    _, events = _run(p, p.t + 30.0)
    assert events == []


def test_relearn_restarts_the_teach_in_of_a_tool_or_everything(taught) -> None:  # type: ignore[no-untyped-def]
    p = copy.deepcopy(taught[1])
    got = p.relearn(tool=2)
    assert got == {"tool": 2, "program": None, "segments": 3}  # lines 50, 60, 70
    _until_line(p, 60)
    assert p.monitor_status()["state"] == "teaching"
    _until_line(p, 20)
    assert p.monitor_status()["state"] == "watching"
    assert p.relearn(program="O1001")["segments"] == 7
    _until_line(p, 40)
    assert p.monitor_status()["state"] == "teaching"
    # the knob: a new N restarts every block's teach-in
    q = copy.deepcopy(taught[1])
    q.set_knob("teach_parts", 3)
    _until_line(q, 20)
    assert q.monitor_status()["state"] == "teaching"
    # band_factor changes the bands, not what was taught
    r = copy.deepcopy(taught[1])
    _until_line(r, 40)
    wide = copy.deepcopy(r)
    wide.set_knob("band_factor", 8.0)
    a, b = r.step(BLOCK), wide.step(BLOCK)
    ok = np.isfinite(a["mon_upper"])
    assert ok.any() and np.all(b["mon_upper"][ok] > a["mon_upper"][ok])
    assert wide.monitor_status()["state"] == "watching"


def test_inject_and_relearn_refuse_bad_input_by_name(taught) -> None:  # type: ignore[no-untyped-def]
    p = copy.deepcopy(taught[2])
    bad = [
        (dict(kind="flood"), "kind"),
        (dict(kind="breakage", size=-1e-4), "size"),
        (dict(kind="breakage", size=math.nan), "size"),
        (dict(kind="breakage", size="big"), "size"),
        (dict(kind="collision", size=0.5), "size"),
        (dict(kind="missing_tool", size=1.5), "size"),
        (dict(kind="breakage", at_t=p.t - 1.0), "at_t"),
        (dict(kind="breakage", at_t=math.inf), "at_t"),
        (dict(kind="breakage", at_part=0), "at_part"),
        (dict(kind="breakage", at_part=1.5), "at_part"),
        (dict(kind="breakage", at_t=p.t + 1, at_part=99), "at_t"),
    ]
    for kw, name in bad:
        with pytest.raises(ParameterError) as e:
            p.inject(**kw)  # type: ignore[arg-type]
        assert e.value.name == name, kw
        assert repr(kw.get(name)) in str(e.value) or name == "at_t"
    assert _proc(p).ps.pending == []
    for kw, name in ((dict(tool=0), "tool"), (dict(program=""), "program")):
        with pytest.raises(ParameterError) as e:
            p.relearn(**kw)  # type: ignore[arg-type]
        assert e.value.name == name
    got = p.inject("breakage")
    assert got["size"] == 0.4e-3 and got["at_t"] is None and got["at_part"] is None
    # a scenario without a part program has nothing to inject into, and no process part:
    # it streams none of the monitor's channels (the dashboard draws no monitor chart)
    q = LivePipeline("seed000-weight")
    with pytest.raises(ParameterError) as e:
        q.inject("breakage")
    assert e.value.name == "kind" and "part program" in str(e.value)
    out = q.step(10)
    assert "mon_f" not in out and q.monitor_status()["state"] == "off"
    assert not [c for c in q.channels() if c.group == "monitor"]
    assert q.part("process") is None and "process" not in [s["name"] for s in q.parts()]


def test_a_checkpoint_resumes_the_teach_in_and_the_events(taught, tmp_path: Path) -> None:  # type: ignore[no-untyped-def]
    p = copy.deepcopy(taught[3])
    p.relearn(tool=2)  # mid teach-in for tool 2
    p.inject("breakage", at_t=p.t + 2.0)
    p.inject("collision", at_part=int(p.monitor_status()["part"]) + 1)  # type: ignore[call-overload]
    save_checkpoint(tmp_path / "ck.npz", p.state())
    q = LivePipeline("default", seed=3)
    q.restore(load_checkpoint(tmp_path / "ck.npz"))
    assert q.knob_values()["teach_parts"] == TEACH
    a, ea = _run(p, p.t + 30.0)
    b, eb = _run(q, q.t + 30.0)
    assert ea and [e.as_dict() | {"id": ""} for e in ea] == [e.as_dict() | {"id": ""} for e in eb]
    for k in a:
        np.testing.assert_array_equal(a[k], b[k], err_msg=k)
    assert p.process_truths() == q.process_truths()
    assert {t["kind"] for t in p.process_truths()} == {"breakage", "collision"}


#: seeds of the live Monte Carlo (besides SEEDS): each teaches a pipeline, then three
#: breakages (lines 20, 40, 60), a collision, a missing tool and a minute of good parts
MC_SEEDS = tuple(range(10, 30))


def _mc_seed(seed: int) -> dict[str, list[float]]:
    p = _taught(seed)
    rng = np.random.default_rng([7, seed])
    out: dict[str, list[float]] = {"breakage": [], "collision": [], "missing_tool": []}
    _, events = _run(p, p.t + 60.0)
    out["false"] = [float(len(events))]
    for kind, line in (("breakage", 20), ("breakage", 40), ("breakage", 60),
                       ("collision", 40), ("missing_tool", 60)):  # fmt: skip
        _until_line(p, 10)  # one event per part
        _inject_mid_cut(p, kind, line, float(rng.uniform(0.3, 0.7)))
        run = _proc(p).ps.run
        assert run is not None
        block_s = run.n_total * _proc(p).sample_time
        cols, events, truth = _past_event(p, 1.0)
        found = [e for e in events if e.kind == kind and e.t >= truth["t"]]
        start = float(truth["t"])
        if kind == "collision":
            over = np.flatnonzero((cols["t"] >= start) & (cols["mon_f"] > cols["mon_extreme"]))
            start = float(cols["t"][over[0]]) if over.size else math.inf
        rev = 60.0 / RPM[line]
        # delay in the target's unit: revolutions, seconds, blocks (NaN: missed)
        scale = {"breakage": 1.0 / rev, "collision": 1.0, "missing_tool": 1.0 / block_s}[kind]
        out[kind].append((found[0].t - start) * scale if found else math.nan)
    return out


@pytest.mark.slow
def test_live_detection_over_many_seeds() -> None:
    """20 seeds: 60 breakages, 20 collisions, 20 missing tools, 20 minutes of good parts;
    every event found within its target, no event on good parts."""
    res = [_mc_seed(s) for s in MC_SEEDS]
    br = np.array([d for r in res for d in r["breakage"]])
    co = np.array([d for r in res for d in r["collision"]])
    mi = np.array([d for r in res for d in r["missing_tool"]])
    false = sum(r["false"][0] for r in res)
    print(
        f"\nlive: breakage {np.isfinite(br).sum()}/{br.size} found, delay max "
        f"{np.nanmax(br):.2f} rev; collision {np.isfinite(co).sum()}/{co.size}, max "
        f"{1e3 * np.nanmax(co):.2f} ms from the crossing; missing {np.isfinite(mi).sum()}/"
        f"{mi.size}, max {np.nanmax(mi):.3f} of its block; false events {false:g} in {len(res)} min"
    )
    assert np.isfinite(br).all() and np.all((br >= 0) & (br <= 2.0))
    assert np.isfinite(co).all() and np.all((co >= 0) & (co <= 5e-3))
    # a missing tool within its block (line 60: 5 s at 100 % override)
    assert np.isfinite(mi).all() and np.all((mi >= 0) & (mi <= 1.0))
    assert false == 0
