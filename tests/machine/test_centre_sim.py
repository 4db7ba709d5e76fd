"""The machining centre's simulation: a part, its drives, its spindle, its events."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest

from machine.centre import kernel as kn
from machine.centre.params import CentreParams
from machine.centre.program import Block, Cut, Program, default_program, default_tools
from machine.centre.sim import CentreRecord, CentreState, MachiningCentre, trapezoid_time
from machine.errors import ParameterError
from machine.process import ProcessEvent

PART_SAMPLES = 320_000  # one default part is ~30.5 s at 10 kHz


def run(m: MachiningCentre, st: CentreState, n: int, chunk: int = 5000) -> tuple[
    CentreState, CentreRecord
]:  # fmt: skip
    """``n`` samples in chunks, joined into one record."""
    recs = []
    left = n
    while left > 0:
        st, rec = m.step(st, min(chunk, left))
        recs.append(rec)
        left -= rec.n
    return st, join(recs)


def join(recs: list[CentreRecord]) -> CentreRecord:
    cat = np.concatenate
    return CentreRecord(
        recs[0].k0, cat([r.t for r in recs]), cat([r.rows for r in recs], axis=1),
        cat([r.tool for r in recs]), cat([r.line for r in recs]), cat([r.part for r in recs]),
        cat([r.override for r in recs]), cat([r.vb for r in recs]), recs[0].program,
        [e for r in recs for e in r.events],
    )  # fmt: skip


@pytest.fixture(scope="module")
def part() -> tuple[MachiningCentre, CentreState, CentreRecord]:
    m = MachiningCentre(override_prob=0.0)
    st, rec = run(m, m.initial_state(seed=0), PART_SAMPLES)
    return m, st, rec


def _steady(rec: CentreRecord, line: int) -> np.ndarray:
    """Samples of ``line`` in full engagement, the first and last fifth left out."""
    idx = np.flatnonzero((rec.line == line) & (rec.signal("engaged") > 0.999))
    cut = len(idx) // 5
    return idx[cut:-cut]


def test_a_part_runs_its_program_with_the_cnc_identities(part) -> None:  # type: ignore[no-untyped-def]
    m, st, rec = part
    lines = [b.line for b in m.program.blocks]
    seen = [int(x) for x in rec.line[np.r_[True, np.diff(rec.line) != 0]]]
    assert seen[: len(lines)] == lines and st.part == 1 and rec.part[-1] == 1
    # the tool in the spindle changes at the tool changes, cuts only in cut blocks
    assert dict(zip(rec.line, rec.tool, strict=True))[60] == 1
    assert {int(rec.tool[i]) for i in np.flatnonzero(rec.line == 140)} == {2}
    cut_lines = {b.line for b in m.program.blocks if b.cut is not None}
    engaged_lines = set(np.unique(rec.line[rec.signal("engaged") > 0]).tolist())
    assert engaged_lines == cut_lines
    assert rec.program == "O2001" and np.all(rec.override == 1.0)
    # time is one 10 kHz sample apart throughout
    assert np.allclose(np.diff(rec.t), 1e-4) and rec.t[0] == 0.0
    part_time = np.flatnonzero(rec.part == 1)[0] * 1e-4
    assert 28.0 < part_time < 33.0


def test_the_spindle_holds_each_programmed_speed_and_the_axes_follow(part) -> None:  # type: ignore[no-untyped-def]
    _, _, rec = part
    for line, rpm in ((60, 3000.0), (140, 8000.0), (250, 10000.0)):
        s = _steady(rec, line)
        speed = rec.signal("S.speed")[s]
        assert abs(speed.mean() / rpm - 1.0) < 0.002, line
        # the speed dips under the cut by well under 1 %
        assert np.ptp(speed) < 0.01 * rpm, line
    for a in "XYZ":
        err = rec.signal(f"{a}.q_cmd") - rec.signal(f"{a}.x_load")
        # following error with feed-forward: tens of micrometres at most
        assert np.abs(err).max() < 60e-6, a


def test_z_holds_its_weight_without_a_counterbalance(part) -> None:  # type: ignore[no-untyped-def]
    m, _, rec = part
    z = m.params.z
    still = np.flatnonzero((rec.line == 10) & (rec.t > 0.5))
    weight = z.load_mass * 9.81 / z.force_constant
    assert rec.signal("Z.i_m")[still].mean() == pytest.approx(weight, rel=0.01)
    assert abs(rec.signal("Y.i_m")[still].mean()) < 0.02


def test_the_spindle_power_is_its_idle_power_in_the_air_and_more_in_the_cut(part) -> None:  # type: ignore[no-untyped-def]
    m, _, rec = part
    sp = m.params.spindle
    air = np.flatnonzero(rec.line == 240)[500:]  # 10,000 rpm, feeding in the air
    p_air = rec.signal("S.power")[air].mean()
    # warming up: between the warm and the cold idle power
    assert sp.idle_power(10000) < p_air < sp.idle_power(10000, warm=False)
    s = _steady(rec, 140)
    w = rec.signal("S.speed_true")[s] * math.pi / 30
    p_cut = (rec.signal("S.torque_cut")[s] * w).mean()
    gained = (
        rec.signal("S.power")[s].mean()
        - rec.signal("S.power")[np.flatnonzero(rec.line == 135)[500:]].mean()
    )
    # the power above idle is the cutting power (energy balance), within 3 %
    assert gained == pytest.approx(p_cut, rel=0.03)
    assert p_cut > 300.0


def test_the_spindle_current_is_a_low_pass_view_of_the_cutting_torque(part) -> None:  # type: ignore[no-untyped-def]
    m, _, rec = part
    s = _steady(rec, 140)
    kt = m.params.spindle.torque_constant
    cut = rec.signal("S.torque_cut")[s]
    motor = rec.signal("S.current")[s] * kt

    def line(x: np.ndarray, f: float) -> float:
        t = np.arange(len(x)) * 1e-4
        return float(2 * abs(np.mean((x - x.mean()) * np.exp(-2j * np.pi * f * t))))

    tooth = 8000 / 60 * 3  # 400 Hz
    # the mean torque is carried, the tooth-passing ripple filtered (inertia + 30 Hz loop)
    idle = m.params.spindle.idle_torque(8000)
    assert motor.mean() - cut.mean() == pytest.approx(idle, rel=0.25)
    assert line(motor, tooth) < 0.1 * line(cut, tooth)


def test_the_x_axis_rings_at_its_axial_mode_after_a_rapid(part) -> None:  # type: ignore[no-untyped-def]
    m, _, rec = part
    # after the rapid of line 120 stops, scale and encoder differ by the spring's stretch
    end = np.flatnonzero(rec.line == 120)[-1]
    d = (rec.signal("X.q_m") - rec.signal("X.q_l"))[end - 2000 : end + 1500]
    d = d - np.median(d)
    x = np.abs(np.fft.rfft(d * np.hanning(len(d)), 2**16))
    f = np.fft.rfftfreq(2**16, 1e-4)
    band = (f > 60) & (f < 300)
    peak = f[band][np.argmax(x[band])]
    f_r, f_a = m.params.x.mode_hz(m.blank)
    assert peak == pytest.approx(f_a, rel=0.1) or peak == pytest.approx(f_r, rel=0.1)


def test_a_step_leaves_its_state_alone_and_runs_the_same_in_any_chunks() -> None:
    m = MachiningCentre()
    st0 = m.initial_state(seed=3)
    st1, whole = run(m, st0, 40_000, chunk=40_000)
    st2, parts = run(m, st0, 40_000, chunk=777)
    assert np.array_equal(whole.rows, parts.rows)
    assert np.array_equal(whole.line, parts.line) and np.array_equal(whole.vb, parts.vb)
    assert st0.k == 0 and st0.run is None and st1.k == st2.k == 40_000
    # a copied state continues exactly like the original
    _, a = m.step(st1, 3000)
    _, b = m.step(st1.copy(), 3000)
    assert np.array_equal(a.rows, b.rows)


def test_different_seeds_give_different_noise_and_shop_draws() -> None:
    m = MachiningCentre(override_prob=1.0)
    _, a = m.step(m.initial_state(seed=1), 2000)
    _, b = m.step(m.initial_state(seed=2), 2000)
    assert not np.array_equal(a.signal("X.i_m"), b.signal("X.i_m"))
    assert a.override[0] != 1.0 and b.override[0] != 1.0


def _one_cut_program() -> Program:
    t1, t2, t3 = default_tools()
    mm = 1e-3
    f = 0.06e-3 * 3 * 8000 / 60
    blocks = (
        Block(10, "tool_change", tool=2, seconds=0.1),
        Block(20, "spindle", rpm=8000.0),
        Block(30, "rapid", (-6 * mm, -3 * mm, -10 * mm)),
        Block(40, "feed", (94 * mm, -3 * mm, -10 * mm), feed=f, cut=Cut(10 * mm, 0.25, True)),
        Block(50, "rapid", (94 * mm, -3 * mm, 20 * mm)),
        Block(60, "end", seconds=0.1),
    )
    return Program("O7", blocks, (t1, t2, t3), start=(0.0, 0.0, 0.02))


def _event_run(
    ev: ProcessEvent | None, n: int = 60_000
) -> tuple[MachiningCentre, CentreState, CentreRecord]:
    m = MachiningCentre(program=_one_cut_program(), events=[ev] if ev else [], override_prob=0.0,
                        depth_spread=0.0)  # fmt: skip
    st, rec = run(m, m.initial_state(seed=0), n)
    return m, st, rec


def _rev_pattern(torque: np.ndarray, rpm: float) -> float:
    """Once-per-revolution share of the torque (seed003 (8)'s harmonic over the mean)."""
    t = np.arange(len(torque)) * 1e-4
    return float(2 * abs(np.mean(torque * np.exp(-2j * np.pi * rpm / 60 * t))) / torque.mean())


def test_a_broken_tooth_gives_a_once_per_revolution_pattern_that_stays_with_the_tool() -> None:
    _, _, clean = _event_run(None)
    m, st, rec = _event_run(ProcessEvent("breakage", 0, 40, 0.4, 0.3e-3, flute=1))
    (ev,) = rec.events
    assert (ev.kind, ev.tool, ev.line, ev.part) == ("breakage", 2, 40, 0)
    k = ev.sample - rec.k0
    cut = np.flatnonzero((rec.line == 40) & (rec.signal("engaged") > 0.999))
    before = cut[(cut < k) & (cut > k - 3000)]
    after = cut[(cut > k + 300) & (cut < k + 3300)]
    tq = rec.signal("S.torque_cut")
    # 0.3 mm lost > the 0.06 mm feed per tooth: that flute cuts nothing, the next a
    # double chip; the runout alone made a small pattern before
    assert _rev_pattern(tq[before], 8000) < 0.3 < 0.6 < _rev_pattern(tq[after], 8000)
    # the same material goes (the next flute takes the broken one's chip), but the broken
    # flute's edge no longer rubs: the mean torque drops by one flute's edge torque,
    # R K_te a_p (window / 2 pi) -- half the torque of this light cut, a sixth of it lost
    t2 = m.program.tool(2)
    k_te = t2.coefficients(rec.vb[before].mean())[2]
    edge = t2.radius * k_te * 10e-3 * (math.pi - math.acos(2 * 0.25 - 1)) / (2 * math.pi)
    # (at most that: near the window's exit the runout leaves no chip, and no rubbing)
    assert 0.85 * edge < tq[before].mean() - tq[after].mean() <= edge
    assert np.array_equal(clean.signal("S.torque_cut")[:k], tq[:k])
    assert st.tools[2].broken and st.tools[2].dr[1] == pytest.approx(-0.3e-3)
    fresh = m.replace_tool(st, 2)
    assert not fresh.tools[2].broken and fresh.tools[2].instance == 2 and st.tools[2].broken


def test_a_missing_tool_cuts_nothing_and_the_spindle_falls_to_idle_power() -> None:
    m, st, rec = _event_run(ProcessEvent("missing_tool", 0, 40, 0.5, 1.0))
    (ev,) = rec.events
    k = ev.sample - rec.k0
    on = rec.line == 40
    assert np.all(rec.signal("S.torque_cut")[k + 1 :][on[k + 1 :]] == 0.0)
    assert rec.signal("S.torque_cut")[k - 1000 : k].mean() > 0.5
    p = rec.signal("S.power")
    idle = m.params.spindle.idle_power(8000, warm=False)
    assert p[k + 2000 : k + 4000].mean() < idle < p[k - 2000 : k].mean()
    assert st.tools[2].lost == 1.0


def test_a_collision_drives_the_feed_up_and_the_forces_with_it() -> None:
    _, _, clean = _event_run(None)
    _, _, rec = _event_run(ProcessEvent("collision", 0, 40, 0.3, 4.0))
    (ev,) = rec.events
    k = ev.sample - rec.k0
    fy = np.abs(rec.signal("Y.f_process"))
    ref = np.abs(clean.signal("Y.f_process"))[k - 2000 : k].mean()
    # 4x the chip; the edge forces (half the force of this light cut) stay: ~2x
    assert fy[k + 200 : k + 2000].mean() > 1.7 * ref
    v = np.gradient(rec.signal("X.q_cmd"), 1e-4)
    assert v[k + 10] == pytest.approx(4.0 * 0.024, rel=1e-6)


def test_an_event_injected_now_lands_in_the_running_cut_or_waits_for_one() -> None:
    m = MachiningCentre(program=_one_cut_program(), override_prob=0.0)
    st = m.initial_state(seed=0)
    st, _ = m.step(st, 100)  # the tool change: no cut
    st2, now = m.inject(st, "missing_tool", 1.0)
    assert not now and len(st2.pending) == 1 and not st.pending
    st3, rec = run(m, st2, 60_000)
    (ev,) = rec.events
    assert ev.line == 40 and ev.kind == "missing_tool"
    # the next part's cut: injected while it runs, it starts at the next sample
    st4, _ = run(m, st3, 20_000)
    assert st4.run is not None and m.program.blocks[st4.run.index].line == 40
    assert st4.run.cp[kn.CP_ACTIVE] == 1.0
    st5, now = m.inject(st4, "breakage", 0.2e-3, flute=0)
    assert now and not st5.pending
    _, rec5 = m.step(st5, 10)
    assert [(e.kind, e.sample) for e in rec5.events] == [("breakage", st4.k)]


def test_a_feed_hold_stops_the_axes_and_resuming_finishes_the_block() -> None:
    m = MachiningCentre(program=_one_cut_program(), override_prob=0.0)
    st, _ = run(m, m.initial_state(seed=0), 20_000)
    assert st.run is not None and m.program.blocks[st.run.index].line == 40
    held = m.set_overrides(st, feed=0.0)
    held, rec = run(m, held, 10_000)
    v = np.gradient(rec.signal("X.q_cmd"), 1e-4)
    assert np.all(np.abs(v[3000:]) < 1e-9) and held.run is not None
    _, rec2 = run(m, m.set_overrides(held, feed=1.0), 40_000)
    assert 50 in set(rec2.line.tolist())
    with pytest.raises(ParameterError, match="feed_override"):
        m.set_overrides(st, feed=2.0)


def test_wear_grows_with_cutting_time_and_a_worn_tool_is_replaced() -> None:
    t1, t2, t3 = default_tools()
    short = replace(t2, life=14.0, life_spread=0.0)
    prog = _one_cut_program()
    prog = Program(prog.name, prog.blocks, (t1, short, t3), start=prog.start)
    m = MachiningCentre(program=prog, override_prob=0.0, depth_spread=0.0)
    st, rec = run(m, m.initial_state(seed=0), 400_000)
    cuts = []  # per part: flank wear and mean cutting torque in the steady cut
    for p in np.unique(rec.part):
        s = np.flatnonzero((rec.part == p) & (rec.line == 40) & (rec.signal("engaged") > 0.999))
        if len(s) > 10_000:
            cuts.append((rec.vb[s].mean(), rec.signal("S.torque_cut")[s].mean()))
    vb, tq = np.array(cuts).T
    first = int(np.argmax(np.diff(vb) < 0)) + 1  # the first part after the replacement
    assert 2 <= first < len(vb)
    assert np.all(np.diff(vb[:first]) > 0) and np.all(np.diff(tq[:first]) > 0)
    assert vb[first - 1] > 0.2e-3 and vb[first] < 0.1e-3 and tq[first] < tq[first - 1]
    assert tq[first - 1] > 1.2 * tq[0]
    assert st.tools[2].instance >= 2 and st.tool_changes >= 1


def test_the_machine_refuses_a_program_outside_its_travel_or_speed() -> None:
    t = default_tools()
    far = Program("O8", (Block(10, "rapid", (0.9, 0.0, 0.1)),), t)
    with pytest.raises(ParameterError, match=r"line N10\.target\.X.*travel"):
        MachiningCentre(program=far)
    fast = Program("O8", (Block(10, "tool_change", tool=1), Block(20, "spindle", rpm=20_000.0)), t)
    with pytest.raises(ParameterError, match=r"line N20\.rpm"):
        MachiningCentre(program=fast)
    with pytest.raises(ParameterError, match="n_layers"):
        MachiningCentre(n_layers=0)
    m = MachiningCentre()
    with pytest.raises(ParameterError, match="'n'"):
        m.step(m.initial_state(), 0)
    with pytest.raises(ParameterError, match="name"):
        m.step(m.initial_state(), 10)[1].signal("X.nope")


def test_the_default_machine_and_program_agree_with_the_docs() -> None:
    m = MachiningCentre()
    assert m.params == CentreParams() and m.program == default_program()
    assert m.blank == pytest.approx(2700 * 0.1 * 0.06 * 0.04)


def test_a_scheduled_event_lands_on_its_line_and_place_in_its_part() -> None:
    m = MachiningCentre(override_prob=0.0)
    st = m.schedule(m.initial_state(seed=0), ProcessEvent("collision", 0, 250, 0.25, 3.0))
    st = m.schedule(st, ProcessEvent("breakage", 0, 140, 0.5, 0.3e-3))
    st, rec = run(m, st, PART_SAMPLES)
    got = sorted((e.line, e.kind, e.part) for e in rec.events)
    assert got == [(140, "breakage", 0), (250, "collision", 0)]
    (c,) = [e for e in rec.events if e.kind == "collision"]
    on = np.flatnonzero(rec.line == 250)
    # a quarter into the block's nominal duration (the collision shortens the block)
    blk = next(b for b in m.program.blocks if b.line == 250)
    nominal = round(trapezoid_time(0.040, blk.feed, 3.0) / 1e-4)
    assert c.sample - on[0] == int(0.25 * nominal)
    assert not st.pending
    with pytest.raises(ParameterError, match=r"event\.line"):
        m.schedule(st, ProcessEvent("breakage", 0, 30, 0.5, 0.3e-3))


def test_program_variants_scale_the_spindle_and_the_feed_together() -> None:
    from machine.centre.program import program_variant

    base, v = default_program(), program_variant(3)
    assert v.name == "O2004" and program_variant(0) == default_program()
    for a, b in zip(base.blocks, v.blocks, strict=True):
        assert b.rpm == pytest.approx(0.8 * a.rpm)
        if a.cut is not None:
            assert b.feed == pytest.approx(0.8 * a.feed)
    with pytest.raises(ParameterError, match="rpm_scale"):
        default_program(rpm_scale=2.0)


def _air_program() -> Program:
    """T2 at 8,000 rpm dwelling in the air for 3 s."""
    blocks = (
        Block(10, "tool_change", tool=2, seconds=0.1),
        Block(20, "spindle", rpm=8000.0),
        Block(30, "dwell", seconds=3.0),
        Block(40, "end", seconds=0.1),
    )
    return Program("O6", blocks, default_tools(), start=(0.05, 0.05, 0.02))


def _circle_response(params: CentreParams) -> dict[str, complex]:
    """The carriages' phasors over the commanded 5 um circle at 8,000 rpm (in the air)."""
    m = MachiningCentre(params, program=_air_program(), override_prob=0.0)
    st, _ = run(m, m.initial_state(seed=0), 11_000)  # the spindle at 8,000 rpm
    st = m.set_modulation(st, 5e-6, 0.7)
    st, _ = run(m, st, 3000)  # settle
    _, rec = run(m, st, 6000)
    assert rec.signal("engaged").max() == 0.0
    psi = rec.signal("S.psi")
    out = {}
    for axis, phase in (("X", 0.0), ("Y", -math.pi / 2)):
        x = rec.signal(f"{axis}.x_load")
        out[axis] = 2 * np.mean((x - x.mean()) * np.exp(-1j * (psi + 0.7 + phase))) / 5e-6
    return out


def test_the_modulation_circle_moves_the_carriage_as_the_loops_say() -> None:
    from machine.centre.loops import tracking_response

    p = CentreParams()
    got = _circle_response(p)
    want = {a: tracking_response(a, 8000 / 60, p, workpiece=MachiningCentre().blank) for a in "XY"}
    # at 133 Hz X is near its axial mode: amplified (~4.9x), Y (rigid) follows (~1.1x)
    assert abs(want["X"]) > 4.0 and 1.0 < abs(want["Y"]) < 1.2
    # the guides' Coulomb friction (not in the linear loop) acts as damping: Y within
    # 10 % (5 deg of phase), X's mode damped, 13 % lower
    assert abs(got["Y"] - want["Y"]) < 0.1 * abs(want["Y"])
    assert 0.8 < abs(got["X"]) / abs(want["X"]) < 0.95
    # without friction the simulation is the linear loop exactly
    x = replace(p.x, load_coulomb=0.0, motor_coulomb=0.0)
    y = replace(p.y, load_coulomb=0.0, motor_coulomb=0.0)
    smooth = p.with_(x=x, y=y)
    got = _circle_response(smooth)
    for a in "XY":
        want_a = tracking_response(a, 8000 / 60, smooth, workpiece=MachiningCentre().blank)
        assert abs(got[a] - want_a) < 1e-3 * abs(want_a), a
    m = MachiningCentre()
    with pytest.raises(ParameterError, match="a_m"):
        m.set_modulation(m.initial_state(), 1e-3, 0.0)


def test_the_cancelling_modulation_cancels_the_runout() -> None:
    m = MachiningCentre(program=_air_program(), override_prob=0.0)
    st, _ = run(m, m.initial_state(seed=0), 11_000)
    a, th = m.cancelling_modulation(st)
    tool = st.tools[2]
    assert 0 < a < 100e-6
    st = m.set_modulation(st, a, th)
    st, _ = run(m, st, 3000)
    _, rec = run(m, st, 6000)
    psi = rec.signal("S.psi")
    ecc = tool.ecc * np.exp(1j * math.radians(tool.ecc_deg))
    # tool centre = carriage + runout (seed003 (6)): its 1x circle nearly gone
    cx = 2 * np.mean((rec.signal("X.x_load") - rec.signal("X.x_load").mean()) * np.exp(-1j * psi))
    cy = 2 * np.mean((rec.signal("Y.x_load") - rec.signal("Y.x_load").mean()) * np.exp(-1j * psi))
    # a circle z e^{j psi}: x's phasor z, y's phasor -j z; the mean of both estimates z
    z = 0.5 * (cx + 1j * cy)
    assert abs(z + ecc) < 0.5 * abs(ecc)
