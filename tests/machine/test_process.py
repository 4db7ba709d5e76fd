"""Part programs and injected events in the simulator (machine/process.py)."""

from __future__ import annotations

import itertools
import math

import numpy as np
import pytest

from estimators.esc import spindle_harmonic
from machine.errors import ParameterError
from machine.process import (
    PartProgram,
    ProcessEvent,
    ProcessMachine,
    ProgramBlock,
    Tool,
    default_program,
)


def _one_cut(**cut: float) -> PartProgram:
    tool = Tool(number=1, n_flutes=4, eccentricity=0.0)
    blocks = (
        ProgramBlock(10, 1, False, 0.004),
        ProgramBlock(20, 1, True, 0.012, spindle_rpm=1200.0, feed_per_tooth=60e-6, **cut),
        ProgramBlock(30, 1, False, 0.004),
    )
    return PartProgram("O7", blocks, (tool,))


def _cut_record(events: list[ProcessEvent], **cut: float):  # type: ignore[no-untyped-def]
    m = ProcessMachine(_one_cut(**cut), rng=np.random.default_rng(0), events=events)
    recs = m.run_part()
    return next(r for r in recs if r.line == 20), m


def test_a_part_carries_the_program_identities_and_cuts_only_in_cut_blocks() -> None:
    m = ProcessMachine(default_program(), rng=np.random.default_rng(3), override_prob=0.0)
    recs = m.run_part()
    assert [r.line for r in recs] == [b.line for b in m.program.blocks]
    assert [r.tool for r in recs] == [1, 1, 1, 1, 2, 2, 2]
    assert {r.program for r in recs} == {"O1001"}
    for r in recs:
        f = np.hypot(r.fx, r.fy)
        assert (f.max() > 20.0) == r.cut, (r.line, f.max())
        assert np.all(np.diff(r.t) > 0) and r.part == 0
    # samples are consecutive across blocks
    assert all(b.k0 == a.k0 + a.n for a, b in itertools.pairwise(recs))
    assert m.run_part()[0].part == 1


def test_a_broken_tooth_moves_its_chip_to_the_next_flute() -> None:
    ev = ProcessEvent("breakage", 0, 20, 0.5, 0.3e-3, flute=1)
    rec, m = _cut_record([ev])
    (truth,) = rec.events
    k = truth.sample - rec.k0
    assert truth.kind == "breakage" and truth.t == pytest.approx(truth.sample * m.sample_time)
    spr = 250  # samples per revolution at 1200 rpm and 5 kHz
    f = np.hypot(rec.fx, rec.fy)
    before = slice(k - 3 * spr, k - 2 * spr)
    after = slice(k + 2 * spr, k + 3 * spr)
    h_before = abs(spindle_harmonic(f[before], rec.psi[before])) / f[before].mean()
    h_after = abs(spindle_harmonic(f[after], rec.psi[after])) / f[after].mean()
    # no runout: no once-per-revolution pattern before; a strong one after
    assert h_before < 0.02
    assert h_after > 0.5
    # the chip load stays (the next flute takes it); the idle flute's edge (rubbing)
    # force is gone, so the mean force drops, but by less than that edge share
    assert 0.75 * f[before].mean() < f[after].mean() < f[before].mean()


def test_a_chipped_edge_is_a_smaller_pattern_than_a_broken_tooth() -> None:
    spr = 250
    out = []
    for size in (10e-6, 0.3e-3):
        rec, _ = _cut_record([ProcessEvent("breakage", 0, 20, 0.5, size)])
        k = rec.events[0].sample - rec.k0
        f = np.hypot(rec.fx, rec.fy)
        sl = slice(k + 2 * spr, k + 3 * spr)
        out.append(abs(spindle_harmonic(f[sl], rec.psi[sl])) / f[sl].mean())
    assert 0.05 < out[0] < 0.5 * out[1]


def test_collision_raises_the_force_and_a_missing_tool_removes_it() -> None:
    spr = 250
    rec, _ = _cut_record([ProcessEvent("collision", 0, 20, 0.5, 5.0)])
    k = rec.events[0].sample - rec.k0
    f = np.hypot(rec.fx, rec.fy)
    assert f[k + spr : k + 2 * spr].max() > 3.0 * f[k - spr : k].max()
    rec, _ = _cut_record([ProcessEvent("missing_tool", 0, 20, 0.5, 1.0)])
    k = rec.events[0].sample - rec.k0
    f = np.hypot(rec.fx, rec.fy)
    assert f[k - spr : k].mean() > 20.0
    assert np.all(f[k:] == 0.0)


def test_wear_grows_and_a_worn_tool_is_replaced() -> None:
    prog = default_program()
    t1 = prog.tool(1)
    fast = Tool(**{**t1.__dict__, "wear_per_s": 0.2, "wear_limit": 1.0})
    prog = PartProgram(prog.name, prog.blocks, (fast, prog.tool(2)))
    m = ProcessMachine(prog, rng=np.random.default_rng(0))
    m.run_part()
    assert m.tool_changes >= 1
    assert m.instances[1].wear < 1.0


@pytest.mark.parametrize(
    ("make", "field"),
    [
        (lambda: ProcessEvent("wobble", 0, 20), "kind"),
        (lambda: ProcessEvent("collision", 0, 20, 0.5, 0.8), "size"),
        (lambda: ProcessEvent("missing_tool", 0, 20, 0.5, 1.5), "size"),
        (lambda: ProcessEvent("breakage", 0, 20, 1.0, 1e-4), "fraction"),
        (lambda: ProgramBlock(-1, 1, True, 0.01), "line"),
        (lambda: PartProgram("O1", (ProgramBlock(1, 9, True, 0.01),), (Tool(),)), "tool"),
        (lambda: Tool(n_flutes=0), "n_flutes"),
    ],
)
def test_bad_input_is_named(make, field: str) -> None:  # type: ignore[no-untyped-def]
    with pytest.raises(ParameterError, match=field):
        make()


def test_modulation_is_checked() -> None:
    m = ProcessMachine(default_program())
    with pytest.raises(ParameterError, match="a_m"):
        m.set_modulation(math.inf, 0.0)
