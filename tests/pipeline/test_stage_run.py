"""The stage's wiring: the observer's parameters for a simulated stage (issue 34's drift)."""

from __future__ import annotations

from machine.stage import SEED000_FORCE, StageConfig
from machine.stage_params import preset
from server.pipeline.stage_run import observer_params_for


def test_observer_params_for_takes_the_design_given() -> None:
    cfg = StageConfig(params=preset("seed000"), force=SEED000_FORCE)
    plain = observer_params_for(cfg)
    designed = observer_params_for(cfg, q_hz=120.0)
    assert designed.q_hz == 120.0 != plain.q_hz
    # the rest is the stage's own: nominal parameters, sample time, encoder
    assert (designed.J_M, designed.K, designed.sample_time) == (
        cfg.params.J_M,
        cfg.params.K,
        cfg.sample_time,
    )
    assert designed.encoder_resolution == cfg.encoder_resolution
