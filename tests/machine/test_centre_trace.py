"""The machining centre's CNC trace and its signals' names (machine/centre/trace.py, signals.py)."""

from __future__ import annotations

import numpy as np
import pytest

from machine.centre import kernel as kn
from machine.centre import signals
from machine.centre.params import CentreParams
from machine.centre.program import Block, Cut, Program, default_tools
from machine.centre.sim import CentreRecord, MachiningCentre
from machine.centre.trace import MEAN_ROWS, TRUTH_ROWS, CncTrace, TraceParams, TraceRecord
from machine.errors import ParameterError
from machine.process import ProcessEvent

RPM = 8000.0
TOOTH_HZ = RPM / 60 * 3  # 400 Hz: above a 500 Hz trace's Nyquist frequency


def _program() -> Program:
    mm = 1e-3
    t = default_tools()
    f = 0.06e-3 * 3 * RPM / 60
    blocks = (
        Block(10, "tool_change", tool=2, seconds=0.1),
        Block(20, "spindle", rpm=RPM),
        Block(30, "rapid", (-6 * mm, -3 * mm, -10 * mm)),
        Block(40, "feed", (94 * mm, -3 * mm, -10 * mm), feed=f, cut=Cut(10 * mm, 0.25, True)),
        Block(50, "end", seconds=0.1),
    )
    return Program("O5", blocks, t, start=(0.0, 0.0, 0.02))


@pytest.fixture(scope="module")
def run() -> tuple[MachiningCentre, list[CentreRecord]]:
    ev = ProcessEvent("breakage", 0, 40, 0.9, 0.3e-3)
    m = MachiningCentre(program=_program(), events=[ev], override_prob=0.0)
    st = m.initial_state(seed=4)
    recs = []
    for n in [1234, 4321, 999] * 12:  # cycles split across records
        st, rec = m.step(st, n)
        recs.append(rec)
    return m, recs


def export(trace: CncTrace, recs: list[CentreRecord]) -> list[TraceRecord]:
    st = trace.initial_state()
    out = []
    for r in recs:
        st, tr = trace.export(st, r)
        out.append(tr)
    return out


def cat(trs: list[TraceRecord], name: str) -> np.ndarray:
    return np.concatenate([t.signal(name) for t in trs])


def _full(recs: list[CentreRecord]) -> CentreRecord:
    c = np.concatenate
    return CentreRecord(
        0, c([r.t for r in recs]), c([r.rows for r in recs], axis=1), c([r.tool for r in recs]),
        c([r.line for r in recs]), c([r.part for r in recs]), c([r.override for r in recs]),
        c([r.vb for r in recs]), recs[0].program, [e for r in recs for e in r.events],
    )  # fmt: skip


def test_a_trace_of_a_run_in_pieces_is_the_trace_of_the_run_in_one(run) -> None:  # type: ignore[no-untyped-def]
    _, recs = run
    for mode in ("sample", "mean"):
        trace = CncTrace(TraceParams(500.0, mode))
        pieces = export(trace, recs)
        (whole,) = export(trace, [_full(recs)])
        joined = np.concatenate([t.rows for t in pieces], axis=1)
        assert np.array_equal(joined, whole.rows)
        assert np.array_equal(np.concatenate([t.line for t in pieces]), whole.line)
        n = sum(r.n for r in recs)
        assert whole.n == n // 20 and whole.t[0] == pytest.approx(19e-4)


def test_sample_points_per_cycle_mean_averages_efforts_truth_always_averaged(run) -> None:  # type: ignore[no-untyped-def]
    _, recs = run
    full = _full(recs)
    f = 20
    m = full.n // f
    for mode in ("sample", "mean"):
        (tr,) = export(CncTrace(TraceParams(500.0, mode)), [full])
        means = full.rows[:, : m * f].reshape(kn.N_ROWS, m, f).mean(axis=2)
        points = full.rows[:, f - 1 : m * f : f]
        for i, name in enumerate(kn.ROWS):
            averaged = i in TRUTH_ROWS or (mode == "mean" and i in MEAN_ROWS)
            want = means[i] if averaged else points[i]
            assert np.array_equal(tr.rows[i], want), (mode, name)
    # positions are never averaged; the current is in a mean trace
    assert kn.ROWS.index("X.q_l") not in MEAN_ROWS and kn.ROWS.index("X.i_m") in MEAN_ROWS


def _line(x: np.ndarray, f_hz: float, fs: float) -> float:
    """Amplitude of the component of ``x`` at ``f_hz`` (a single-bin DFT)."""
    t = np.arange(len(x)) / fs
    return float(2 * abs(np.mean((x - x.mean()) * np.exp(-2j * np.pi * f_hz * t))))


def _steady(line: np.ndarray, engaged: np.ndarray, t: np.ndarray, t_event: float) -> np.ndarray:
    idx = np.flatnonzero((line == 40) & (engaged > 0.999) & (t < t_event))
    return idx[len(idx) // 4 :]


def test_the_tooth_line_folds_back_at_full_strength_point_sampled_and_by_sinc_averaged(run) -> None:  # type: ignore[no-untyped-def]
    _, recs = run
    full = _full(recs)
    t_ev = full.events[0].t
    s = _steady(full.line, full.signal("engaged"), full.t, t_ev)
    at_full = _line(full.signal("Y.i_m")[s], TOOTH_HZ, 1e4)
    assert at_full > 0.01  # the tooth line is in the current (A)
    alias = 500.0 - TOOTH_HZ  # 400 Hz seen at 100 Hz
    got = {}
    for mode in ("sample", "mean"):
        trs = export(CncTrace(TraceParams(500.0, mode)), recs)
        ti, li, en = cat(trs, "Y.i_m"), np.concatenate([t.line for t in trs]), cat(trs, "engaged")
        tt = np.concatenate([t.t for t in trs])
        got[mode] = _line(ti[_steady(li, en, tt, t_ev)], alias, 500.0)
    assert got["sample"] == pytest.approx(at_full, rel=0.1)
    # a one-cycle boxcar: |sinc(400 / 500)| = 0.234
    assert got["mean"] / got["sample"] == pytest.approx(abs(np.sinc(TOOTH_HZ / 500.0)), rel=0.1)
    # a 1 kHz trace has it where it is
    trs = export(CncTrace(TraceParams(1000.0, "sample")), recs)
    ti, li, en = cat(trs, "Y.i_m"), np.concatenate([t.line for t in trs]), cat(trs, "engaged")
    tt = np.concatenate([t.t for t in trs])
    assert _line(ti[_steady(li, en, tt, t_ev)], TOOTH_HZ, 1000.0) == pytest.approx(at_full, rel=0.1)


def test_events_land_on_the_trace_sample_of_their_cycle(run) -> None:  # type: ignore[no-untyped-def]
    _, recs = run
    (ev,) = [e for r in recs for e in r.events]
    trs = export(CncTrace(TraceParams(1000.0)), recs)
    found = [(t, i) for t in trs for e, i in zip(t.events, t.trace_index, strict=True)]
    ((tr, i),) = found
    assert tr.events[0] is ev
    # the cycle holding the event's first sample: its stamp is at or after the event
    assert 0.0 <= tr.t[i] - ev.t < 1e-3


def test_trace_parameters_are_checked() -> None:
    with pytest.raises(ParameterError, match="rate_hz"):
        TraceParams(700.0)
    with pytest.raises(ParameterError, match="mode"):
        TraceParams(500.0, "average")
    with pytest.raises(ParameterError, match="divisor"):
        CncTrace(TraceParams(2500.0), sample_time=3e-4)


def test_a_record_out_of_order_is_refused(run) -> None:  # type: ignore[no-untyped-def]
    _, recs = run
    trace = CncTrace()
    st, _ = trace.export(trace.initial_state(), recs[0])
    with pytest.raises(ParameterError, match=r"rec\.k0"):
        trace.export(st, recs[2])


def test_the_description_names_every_exported_column(run) -> None:  # type: ignore[no-untyped-def]
    _, recs = run
    (tr,) = export(CncTrace(TraceParams(500.0)), [_full(recs)])
    d = signals.description_dict(rate_hz=500.0)
    cols = signals.columns(tr)
    # checked against the machine description's schema (issue 30), and read back whole
    desc = signals.description(rate_hz=500.0)
    assert desc.to_dict() == d and desc.axis_names == ("X", "Y", "Z")
    assert desc.axis("X").required_roles == ("q_m", "i_m", "q_l")
    assert d["sample_time"] == 0.002
    assert {a: v["kind"] for a, v in d["axes"].items()} == {
        "X": "two_inertia", "Y": "rigid", "Z": "rigid",
    }  # fmt: skip
    named = [c for a in d["axes"].values() for c in a["signals"].values()]
    named += list(d["spindle"]["signals"].values())
    named += [d["identities"][k] for k in ("tool", "line", "override")]
    assert sorted(named) == sorted(c for c in cols if c != "t")
    assert "X_q_l" in cols and "Y_q_l" not in cols
    assert d["axes"]["Z"]["K_t"] == pytest.approx(CentreParams().z.force_constant)
    # truth only when asked, and never under a measured column's name
    truth = signals.columns(tr, truth=True)
    extra = set(truth) - set(cols)
    assert extra and all(c.startswith("true_") for c in extra)
    assert np.array_equal(truth["true_S_torque_cut"], tr.signal("S.torque_cut"))
