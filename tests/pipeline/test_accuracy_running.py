"""The accuracy panel lists the force estimates of the parts that run (issue 31).

On the machining centre the stage's observers do not run (no nominal two-inertia
parameters in a CNC's description): their estimates are not listed as "no reference",
the axes' process forces are. On the stage's scenario every observer runs and is
scored against the truth. A part that pauses (its band above the Nyquist frequency)
leaves the panel and comes back with its windows when it runs again.
"""

from __future__ import annotations

import math

import numpy as np

from server.pipeline.live_pipeline import FORCE_ESTIMATES, LivePipeline
from server.pipeline.machine_view import MachineView
from server.pipeline.part import Block, Channel, LivePart, Outputs, Verdict, needs_band
from server.pipeline.part_registry import registered

BLOCK = 125


def test_the_centre_lists_its_running_parts_estimates_only() -> None:
    p = LivePipeline("machining-centre", seed=0)
    for _ in range(5):
        p.step(50)
    running = {s["name"] for s in p.parts() if s["running"]}
    assert "stage" not in running and {"axes"} <= running
    acc = p.accuracy()
    rms = acc["rms"]
    assert isinstance(rms, dict)
    assert not set(FORCE_ESTIMATES) & set(rms)  # f_fixed, f_dfo...: the stage's, not run
    assert {"X.F", "Y.F", "Z.F"} <= set(rms)
    assert tuple(rms) == p.running_force_estimates()
    assert set(p.running_force_estimates()) < set(p.force_estimates())
    assert acc["mode"] == "none" and acc["rms_q"] == {}


def test_the_stage_scenario_scores_every_observer() -> None:
    p = LivePipeline("default", seed=0)
    for _ in range(4):
        p.step(BLOCK)
    rms = p.accuracy()["rms"]
    assert isinstance(rms, dict) and tuple(rms) == FORCE_ESTIMATES
    assert all(math.isfinite(v[0]) for v in rms.values())


class Harmonic(LivePart):
    """A toy force estimate at the 30th spindle order: paused above the Nyquist frequency
    (1250 Hz at 2.5 kHz), it streams the stage's fixed observer's force when it runs."""

    name = "harmonic"
    needs = ("stage",)
    channels = (Channel("f_harmonic", "N m", "30x estimate", "force"),)

    def requires(self, machine: MachineView) -> Verdict:
        return needs_band(machine, 30.0 * machine.spindle_rpm / 60.0, "the 30x order")

    def step(self, block: Block) -> Outputs:
        return {"f_harmonic": np.asarray(block.outputs["f_fixed"], dtype=float)}, []


def test_a_paused_part_leaves_the_panel_and_comes_back() -> None:
    with registered(Harmonic):
        p = LivePipeline("seed000-weight")
    p.step(BLOCK)  # 3000 rpm: 1500 Hz, above 1250: paused
    assert "f_harmonic" in p.force_estimates()
    assert "f_harmonic" not in p.accuracy()["rms"]  # type: ignore[operator]
    p.set_knob("spindle_rpm", 2000.0)  # 1000 Hz: it runs
    for _ in range(3):
        p.step(BLOCK)
    rms = p.accuracy()["rms"]
    assert isinstance(rms, dict) and math.isfinite(rms["f_harmonic"][0])
    assert rms["f_harmonic"][0] > 0.0  # scored on the samples since it runs again
