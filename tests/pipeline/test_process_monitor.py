"""Teach-in envelopes and the detectors of estimators/monitoring/process.py on simulated parts.

The force the monitor sees is the drives' estimate (the seed 000 observer on each feed
axis, scale quantised, current noise), never the simulator's true force.
"""

from __future__ import annotations

import copy
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from estimators.errors import ParameterError
from estimators.monitoring.process import MonitorParams, ProcessMonitor
from harness.eccentricity_loop import ObserverForceSource
from machine.process import ProcessEvent, ProcessMachine, default_program


@pytest.fixture(scope="module")
def taught() -> tuple[ProcessMachine, ObserverForceSource, ProcessMonitor, dict[str, Any]]:
    m = ProcessMachine(default_program(), rng=np.random.default_rng(5), override_prob=0.0)
    obs = ObserverForceSource(
        m.drives, resolution=5e-9, q_hz=1000.0,
        mass_error=0.02, current_noise=0.01, rng=np.random.default_rng(6),
    )  # fmt: skip
    mon = ProcessMonitor(MonitorParams(teach_parts=4))
    st = mon.initial_state()
    for _ in range(4):
        for r in m.run_part():
            fx, fy = obs(r)
            rec = mon.step(st, fx, fy, r.psi, tool=r.tool, program=r.program, line=r.line,
                           new_block=True, override=r.override)  # fmt: skip
            assert rec.teaching and not rec.alarms
    return m, obs, mon, st


def _copy(taught):  # type: ignore[no-untyped-def]
    return copy.deepcopy(taught)


def _part(m, obs, mon, st, chunk: int = 0, air: frozenset[int] = frozenset()):  # type: ignore[no-untyped-def]
    """Run one part (the lines in ``air`` said not to cut); returns (alarms, per-block
    records, block records)."""
    alarms, recs, blocks = [], [], []
    for b in m.program.blocks:
        first = [True]

        def on_chunk(r, first=first):  # type: ignore[no-untyped-def]
            fx, fy = obs(r)
            rec = mon.step(st, fx, fy, r.psi, tool=r.tool, program=r.program, line=r.line,
                           new_block=first[0], override=r.override,
                           cutting=r.line not in air)  # fmt: skip
            first[0] = False
            alarms.extend(rec.alarms)
            recs.append(rec)
            blocks.append(r)

        m.run_block(b, chunk=chunk, on_chunk=on_chunk)
    m.part += 1
    return alarms, recs, blocks


def test_good_parts_raise_no_alarm_and_cut_blocks_have_limits(taught) -> None:  # type: ignore[no-untyped-def]
    m, obs, mon, st = _copy(taught)
    for _ in range(2):
        alarms, recs, blocks = _part(m, obs, mon, st)
        assert alarms == []
    for rec, b in zip(recs, blocks, strict=True):
        assert not rec.teaching
        assert np.isfinite(rec.extreme).all()
        if b.cut:
            core = slice(b.n // 3, 2 * b.n // 3)
            assert np.isfinite(rec.lower[core]).all() and np.isfinite(rec.pattern_limit[core]).all()
            assert np.all(rec.f_mean[core] > rec.lower[core])
            assert np.all(rec.f_mean[core] < rec.upper[core])
        else:
            assert np.isnan(rec.pattern_limit).all()


@pytest.mark.parametrize(
    ("kind", "size"), [("breakage", 0.3e-3), ("collision", 5.0), ("missing_tool", 1.0)]
)
def test_each_event_is_found_by_its_detector_in_time(taught, kind: str, size: float) -> None:  # type: ignore[no-untyped-def]
    m, obs, mon, st = _copy(taught)
    m.events = [ProcessEvent(kind, m.part, 40, 0.5, size)]
    alarms, recs, blocks = _part(m, obs, mon, st)
    (truth,) = [e for b in blocks for e in b.events]
    mine = [a for a in alarms if a.detector == kind]
    assert mine, alarms
    assert all(a.sample >= truth.sample for a in alarms)  # nothing before the event
    rec, b = next((r, b) for r, b in zip(recs, blocks, strict=True) if b.line == 40)
    k_al = mine[0].sample - b.k0
    start = truth.sample
    if kind == "collision":
        # the target counts from the estimated force crossing the extreme limit
        k_ev = truth.sample - b.k0
        start = b.k0 + k_ev + int(np.flatnonzero(rec.f[k_ev:] > rec.extreme[k_ev:])[0])
    delay = (mine[0].sample - start) * m.sample_time
    rev = 60.0 / 1500.0  # line 40 runs at 1500 rpm
    limit = {"breakage": 2 * rev, "collision": 5e-3, "missing_tool": b.n * m.sample_time}[kind]
    assert 0 <= delay <= limit
    assert mine[0].line == 40 and mine[0].tool == 1
    if kind == "breakage":
        # suspected is raised no later than the alarm: the canceller is held in time
        assert rec.suspected[: k_al + 1].any()
        assert not rec.suspected[: truth.sample - b.k0].any()


@pytest.mark.parametrize(("kind", "size"), [("missing_tool", 1.0), ("collision", 5.0)])
def test_a_block_said_not_to_cut_is_watched_by_the_extreme_limit_only(  # type: ignore[no-untyped-def]
    taught, kind: str, size: float
) -> None:
    # line 40 is a cut; said not to cut (a G0, a plunge), it has no band and no pattern
    # limit: losing its force raises nothing, a collision in it still does
    m, obs, mon, st = _copy(taught)
    m.events = [ProcessEvent(kind, m.part, 40, 0.3, size)]
    alarms, recs, blocks = _part(m, obs, mon, st, air=frozenset({40}))
    rec = next(r for r, b in zip(recs, blocks, strict=True) if b.line == 40)
    assert np.isnan(rec.lower).all() and np.isnan(rec.upper).all()
    assert np.isnan(rec.pattern_limit).all() and not rec.suspected.any()
    assert np.isfinite(rec.extreme).all()
    found = [a.detector for a in alarms if a.line == 40]
    assert found == (["collision"] if kind == "collision" else [])
    # the same event in the same block judged as a cut is found
    m, obs, mon, st = _copy(taught)
    m.events = [ProcessEvent(kind, m.part, 40, 0.3, size)]
    alarms, _, _ = _part(m, obs, mon, st)
    assert kind in [a.detector for a in alarms if a.line == 40]


def test_delays_do_not_depend_on_the_chunk_size(taught) -> None:  # type: ignore[no-untyped-def]
    out = []
    for chunk in (0, 250, 97):
        m, obs, mon, st = _copy(taught)
        m.events = [ProcessEvent("breakage", m.part, 20, 0.4, 0.3e-3)]
        alarms, _, _ = _part(m, obs, mon, st, chunk=chunk)
        out.append([(a.detector, a.sample) for a in alarms])
    assert out[0] and out[0] == out[1] == out[2]


def test_the_state_is_a_dict_of_arrays_that_a_checkpoint_keeps(taught, tmp_path: Path) -> None:  # type: ignore[no-untyped-def]
    m, obs, mon, st = _copy(taught)
    np.savez(tmp_path / "monitor.npz", **st)
    with np.load(tmp_path / "monitor.npz") as z:
        back = {k: z[k].copy() for k in z.files}
    assert set(back) == set(st)
    m2, obs2 = copy.deepcopy((m, obs))
    m.events = m2.events = [ProcessEvent("missing_tool", m.part, 60, 0.5, 1.0)]
    a1, r1, _ = _part(m, obs, mon, st)
    a2, r2, _ = _part(m2, obs2, ProcessMonitor(mon.params), back)
    assert [(a.detector, a.sample) for a in a1] == [(a.detector, a.sample) for a in a2]
    np.testing.assert_array_equal(r1[-2].lower, r2[-2].lower)


def test_relearn_forgets_one_tool_only(taught) -> None:  # type: ignore[no-untyped-def]
    _, _, mon, st = _copy(taught)
    assert mon.relearn(st, tool=2) == 3  # lines 50, 60, 70
    seg1 = mon.segment(st, 1, "O1001", 20)
    seg2 = mon.segment(st, 2, "O1001", 60)
    assert not mon.teaching(st, seg1) and mon.teaching(st, seg2)


def test_bad_input_is_named(taught) -> None:  # type: ignore[no-untyped-def]
    _, _, mon, st = _copy(taught)
    z = np.zeros(10)
    with pytest.raises(ParameterError, match="override"):
        mon.step(st, z, z, z, tool=1, program="O1", line=1, new_block=True, override=0.0)
    with pytest.raises(ParameterError, match="fx/fy/psi"):
        mon.step(st, z, z[:5], z, tool=1, program="O1", line=1, new_block=True)
    with pytest.raises(ParameterError, match="teach_parts"):
        MonitorParams(teach_parts=0)


def test_a_program_with_more_blocks_than_segments_says_so_before_step_refuses() -> None:
    # a real CNC program (cnc-mill: 81 sequence numbers) may outgrow max_segments: the live
    # parts ask has_room and leave those blocks unwatched instead of stopping on the error
    mon = ProcessMonitor(MonitorParams(max_segments=2))
    st = mon.initial_state()
    z = np.zeros(8)
    for line in (10, 20):
        assert mon.has_room(st, 1, "O1", line)
        mon.step(st, z, z, z, tool=1, program="O1", line=line, new_block=True)
    assert mon.has_room(st, 1, "O1", 10)  # a known block keeps its segment
    assert not mon.has_room(st, 1, "O1", 30)
    with pytest.raises(ParameterError, match="segments"):
        mon.step(st, z, z, z, tool=1, program="O1", line=30, new_block=True)
