"""The knobs a pipeline offers are its parts' (issue 31, the one machine live).

On the machining centre the knobs are its monitors' two (the spindle's and the axes':
``teach_parts``, ``band_factor``), not the simulated stage's; the stage's scenario
offers every knob; a log or a feed offers none of the simulator's. A knob no part of
the pipeline reads is refused naming the parts that would read it, and nothing changes;
a part that is built but paused keeps its knobs, says why they wait, and takes the value
when it runs again.
"""

from __future__ import annotations

import pytest

from common.errors import ParameterError
from server.pipeline.knobs import KNOB_TABLE, KNOBS, SIMULATOR
from server.pipeline.live_pipeline import LivePipeline
from server.pipeline.machine_view import MachineView
from server.pipeline.part import Block, LivePart, Outputs, Setup, Verdict, needs_band
from server.pipeline.part_registry import BUILTIN, registered

BLOCK = 125


def test_every_knob_names_parts_that_exist() -> None:
    builtin = {name for name, _ in BUILTIN} | {SIMULATOR, "spindle_steps"}
    for k in KNOB_TABLE:
        assert k.parts and set(k.parts) <= builtin, (k.name, k.parts)


def test_the_centre_offers_its_spindle_monitors_knobs_only() -> None:
    p = LivePipeline("machining-centre", seed=0)
    knobs = p.knobs()
    assert sorted(knobs) == ["band_factor", "teach_parts"]
    assert all(k.parts == ("spindle", "axis_monitor") and not k.waiting for k in knobs.values())
    assert sorted(p.knob_values()) == ["band_factor", "teach_parts"]
    assert sorted(p.snapshot()["knobs"]) == ["band_factor", "teach_parts"]  # type: ignore[call-overload]
    p.set_knob("teach_parts", 2)
    assert p.knobs()["teach_parts"].value == 2.0
    before = p.knob_values()
    for name, value, who in (
        ("wear_rate", 1.0, "the wear part"),
        ("spindle_rpm", 2000.0, "the simulated stage"),
        ("tuner", "fast", "the eccentricity part"),
    ):
        with pytest.raises(ParameterError) as e:
            p.set_knob(name, value)
        assert e.value.name == name and e.value.got == value
        assert "one of the knobs this pipeline's parts read: teach_parts, band_factor" in str(
            e.value.expected
        )
        assert f"{name} is read by {who}, which this pipeline does not run" in e.value.expected
    # all or nothing: a good change beside a refused one is not made
    with pytest.raises(ParameterError, match="feed_scale"):
        p.set_knobs({"band_factor": 6.0, "feed_scale": 2.0})
    assert p.knob_values() == before
    # a name that is no knob at all: the table's own refusal
    with pytest.raises(ParameterError, match="'name'"):
        p.set_knob("bogus", 1.0)


def test_the_stage_scenario_offers_every_knob_and_seed000_the_stages() -> None:
    assert set(LivePipeline("default").knobs()) == set(KNOBS)
    weight = LivePipeline("seed000-weight").knobs()
    assert set(weight) == {k.name for k in KNOB_TABLE if k.parts == (SIMULATOR,)}
    assert "spindle_changes" not in weight  # no periodic steps in its script
    assert LivePipeline("default").knobs()["spindle_changes"].parts == ("spindle_steps",)
    assert all(k.parts == (SIMULATOR,) and not k.waiting for k in weight.values())
    with pytest.raises(ParameterError, match="the process, spindle and axis_monitor parts"):
        LivePipeline("seed000-weight").set_knob("teach_parts", 2)


class PausedMonitor(LivePart):
    """A monitor named as the process monitor, watching a 30x spindle pattern: paused
    while that pattern lies above the Nyquist frequency (1250 Hz at 2.5 kHz)."""

    name = "process"

    def __init__(self) -> None:
        self.taught: list[float] = []

    def requires(self, machine: MachineView) -> Verdict:
        return needs_band(machine, 30.0 * machine.spindle_rpm / 60.0, "the 30x pattern")

    def configure(self, setup: Setup) -> None:
        self.taught.append(float(setup.knobs["teach_parts"]))

    def step(self, block: Block) -> Outputs:
        return {}, []


def test_a_paused_part_keeps_its_knobs_and_takes_them_when_it_runs() -> None:
    with registered(PausedMonitor):
        p = LivePipeline("seed000-weight")
    part = p.part("process")
    p.step(BLOCK)  # 3000 rpm: 1500 Hz, paused
    k = p.knobs()["teach_parts"]
    assert k.parts == ("process",)
    assert k.waiting.startswith("the process part does not run (the 30x pattern at 1500 Hz")
    assert k.waiting.endswith(": the value is kept for when it runs")
    p.set_knob("teach_parts", 3)  # stored, not refused
    p.step(BLOCK)
    assert part.taught == []  # not configured while paused
    p.set_knob("spindle_rpm", 2000.0)  # 1000 Hz: it runs, with the value kept
    p.step(BLOCK)
    assert part.taught[-1] == 3.0 and p.knobs()["teach_parts"].waiting == ""
