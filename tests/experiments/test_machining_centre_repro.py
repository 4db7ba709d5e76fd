"""`cutwatch reproduce machining-centre`: the machine's stated numbers and its trace."""

from __future__ import annotations

from pathlib import Path

import pytest

from server.experiments.reproduction import Reproduction
from server.experiments.reproductions import machining_centre as mc


@pytest.fixture(scope="module")
def rep(tmp_path_factory: pytest.TempPathFactory) -> Reproduction:
    return mc.run(quick=True, plot_dir=tmp_path_factory.mktemp("plots"), progress=False)


def test_every_check_holds(rep: Reproduction) -> None:
    assert rep.checks and rep.all_hold, [c for c in rep.checks if not c.holds]


def test_the_stated_numbers(rep: Reproduction) -> None:
    assert 40.0 <= rep.row("x.antiresonance_hz").ours < rep.row("x.first_mode_hz").ours <= 150.0
    assert rep.row("x.stiffness").ours == pytest.approx(169.9, abs=0.5)
    assert rep.row("x.load_mass").ours > 300.0
    for a in "xyz":
        assert 40.0 < rep.row(f"{a}.speed_loop_bandwidth_hz").ours < 70.0
        assert 7.0 < rep.row(f"{a}.position_loop_bandwidth_hz").ours < 11.0
    assert 28.0 < rep.row("part_time").ours < 34.0


def test_the_trace_folds_the_teeth_as_sampling_says(rep: Reproduction) -> None:
    # T2: 400 Hz seen at 100 Hz; a cycle mean passes |sinc(0.8)| = 0.234 of it
    assert rep.row("trace_500hz.sample.tooth_T2_gain").ours == pytest.approx(1.0, abs=0.15)
    assert rep.row("trace_500hz.mean.tooth_T2_gain").ours == pytest.approx(0.234, rel=0.15)
    # T3's folded line lands on the spindle's own line: a cycle mean passes far more
    # than a lone line's 0.413 there
    assert "on the spindle's 167 Hz line" in rep.row("trace_500hz.mean.tooth_T3_gain").condition
    assert rep.row("trace_500hz.mean.tooth_T3_gain").ours > 0.55
    # and every folded line is the sum sampling theory gives (the export's timing)
    for t in (1, 2, 3):
        for mode in ("sample", "mean"):
            name = f"trace_500hz.{mode}.tooth_T{t}_over_folded_sum"
            assert rep.row(name).ours == pytest.approx(1.0, abs=1e-3)
    assert rep.row("trace_500hz.x_ringing_hz").ours == pytest.approx(
        rep.row("x.ringing_hz").ours, abs=3.0
    )


def test_the_spectrum_figure_is_written(rep: Reproduction) -> None:
    (fig,) = rep.figures
    p = Path(fig)
    assert p.name == "machining_centre_spectrum.png" and p.stat().st_size > 20_000
    assert p.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
