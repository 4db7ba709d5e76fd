"""Issue 31: the machining centre became the default scenario, so a service started on an
existing data area finds the checkpoint of the seeds' stage (``default``). The runtime
refuses it (another scenario) and starts fresh, and keeps it beside the checkpoint's
name instead of overwriting it at its first save: nothing is lost, and renamed back it
resumes under its own scenario."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from server.pipeline.checkpoint import load_checkpoint
from server.pipeline.live_pipeline import LivePipeline
from server.pipeline.runtime import MachineRuntime

BLOCK = 125  # 50 ms of the stage


def test_a_checkpoint_of_another_scenario_is_kept_aside_not_overwritten(tmp_path: Path) -> None:
    path = tmp_path / "state" / "pipeline.npz"
    path.parent.mkdir()
    stage = MachineRuntime("m", LivePipeline("default", seed=2), checkpoint=path)
    for _ in range(20):
        stage.step(BLOCK)
    assert stage.save()
    saved = load_checkpoint(path)
    assert saved.scenario == "default" and saved.t == pytest.approx(1.0)

    centre = MachineRuntime("m", LivePipeline(), checkpoint=path)  # the new default
    assert centre.resume() is False
    st = centre.checkpoint_status
    assert "scenario 'machining-centre'" in st["refused"] and "'default'" in st["refused"]
    aside = path.with_name("pipeline.default-simulator.t1.npz")
    assert st["kept_aside"] == str(aside) and aside.exists() and not path.exists()
    centre.step(25)
    assert centre.save() and load_checkpoint(path).scenario == "machining-centre"
    kept = load_checkpoint(aside)  # untouched by the centre's save
    assert kept.scenario == "default" and kept.t == saved.t

    # renamed back, the stage resumes where it was
    aside.replace(path)
    again = MachineRuntime("m", LivePipeline("default", seed=2), checkpoint=path)
    assert again.resume() is True
    a, _ = again.step(BLOCK)
    b, _ = stage.step(BLOCK)
    for k in ("t", "f_adaptive", "J_L_seg"):
        np.testing.assert_array_equal(a[k], b[k])


def test_an_unreadable_checkpoint_is_not_kept_aside(tmp_path: Path) -> None:
    path = tmp_path / "pipeline.npz"
    path.write_bytes(b"not a checkpoint")
    rt = MachineRuntime("m", LivePipeline("default"), checkpoint=path)
    assert rt.resume() is False
    assert "kept_aside" not in rt.checkpoint_status and path.exists()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["pipeline.npz"]
