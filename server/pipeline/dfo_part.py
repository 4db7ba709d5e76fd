"""Seed 002's harmonic observer (DFO) as a live part, on the stage's segment observer.

:class:`DfoPart` runs the DFO through Q(s) (:mod:`server.pipeline.stage_harmonics`) on
the force of the observer with the gated segment identifier's parameters (the stage
part's ``f_segment``): on the fixed one the workpiece's unmodelled inertia biases the
harmonics (measured: 2.8 N m for a true 4.0); on the adaptive (RLS) one its J_L moves at
every spindle step and the 100 Hz acceleration times that error reads as a harmonic
(measured, 100 s of the default scenario: amplitude error median 9 % / p90 46 %, and
after 5 of 6 spindle steps not within 5 % in 2 s; on the segment parameters: 0.8 % /
3 %, within 5 % 40-65 ms after every step). It follows the spindle speed: retuned (state
kept) when the machine's spindle speed changes.

What it needs: the stage part's force, and its highest tooth-passing harmonic below the
Nyquist frequency (at 3000 rpm, 200 Hz: a 500 Hz trace carries it, a 100 Hz one does
not). The true amplitudes are the simulated force's (NaN without the simulator).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from common.errors import ParameterError
from estimators.dfo import Dfo, DfoState
from server.errors import CutwatchError
from server.pipeline.knobs import BASE_RPM
from server.pipeline.machine_view import MachineView
from server.pipeline.part import (
    Block,
    Channel,
    Chart,
    LivePart,
    Outputs,
    Setup,
    Verdict,
    needs_band,
    refuse,
)
from server.pipeline.stage_harmonics import make_dfo
from server.pipeline.stage_part import COLORS, FORCE, StagePart

__all__ = ["HARMONICS", "DfoPart", "DfoPartState"]

HARMONICS = Chart("harmonics", "Tooth-passing harmonics: amplitude", order=50)
_C = COLORS


@dataclass
class DfoPartState:
    """The DFO's frequencies in effect and its state (checkpointed)."""

    frequencies: tuple[float, ...]
    dfo: DfoState


class DfoPart(LivePart):
    """The harmonic observer (module docstring).

    Parameters
    ----------
    stage
        The stage part (its observer's Q(s) is the DFO's channel).
    frequencies
        The tooth-passing harmonics [Hz] at the base spindle speed
        (:data:`~server.pipeline.knobs.BASE_RPM`).
    """

    name = "dfo"
    needs = ("stage",)
    charts = (HARMONICS,)
    channels = (
        *FORCE.series(
            Channel(
                "f_dfo",
                "N m",
                "harmonic observer (DFO) on the segment observer",
                "force",
                color=_C["dfo"],
                legend="DFO",
            ),
            start=5,
        ),
        *HARMONICS.series(
            Channel(
                "h1_true",
                "N m",
                "1st harmonic, true amplitude",
                "harmonics",
                truth=True,
                color=_C["true"],
                legend="1st true",
            ),
            Channel(
                "h1_amp",
                "N m",
                "1st tooth-passing harmonic, DFO amplitude",
                "harmonics",
                color=_C["adaptive"],
                legend="1st DFO",
            ),
            Channel(
                "h2_true",
                "N m",
                "2nd harmonic, true amplitude",
                "harmonics",
                truth=True,
                color=_C["grey"],
                legend="2nd true",
            ),
            Channel(
                "h2_amp",
                "N m",
                "2nd tooth-passing harmonic, DFO amplitude",
                "harmonics",
                color=_C["switching"],
                legend="2nd DFO",
            ),
        ),
    )

    #: why the machine's trace does not carry what the DFO follows, in numbers (set by
    #: the registry on the machining centre: :func:`server.pipeline.centre_rates.dfo_reason`)
    rate_note: str = ""

    def __init__(self, stage: StagePart, frequencies: tuple[float, ...]) -> None:
        self.base = tuple(float(f) for f in frequencies)
        _check_band(self.base, stage.run.front.params.sample_time)
        self.dfo = Dfo(make_dfo(stage.run.front.params, self.base))
        self.dfo_state = self.dfo.initial_state()

    def _frequencies(self, rpm: float) -> tuple[float, ...]:
        ratio = rpm / BASE_RPM
        return tuple(f * ratio for f in self.base)

    def requires(self, machine: MachineView) -> Verdict:
        if self.rate_note:
            return refuse(self.rate_note)
        top = max(self._frequencies(machine.spindle_rpm), default=math.nan)
        return needs_band(machine, top, "the DFO's highest tooth-passing harmonic")

    def configure(self, setup: Setup) -> None:
        """Retune to the spindle speed (the state kept)."""
        self.retune(self._frequencies(setup.machine.spindle_rpm))

    def retune(self, frequencies: tuple[float, ...]) -> None:
        if frequencies != tuple(self.dfo.params.frequencies):
            self.dfo = Dfo(self.dfo.params.with_frequencies(frequencies))

    def step(self, block: Block) -> Outputs:
        if block.discontinuity is not None:  # the break loses the harmonics' phases
            self.dfo_state = self.dfo.initial_state()
        self.dfo_state, dr = self.dfo.step(self.dfo_state, block.outputs["f_segment"])
        f = block.plant.force
        n = block.n
        if block.has_truth and f is not None:
            true = np.asarray(f.amplitudes, dtype=np.float64) * f.gain
        else:
            true = np.full(len(self.base), math.nan)
        return {
            "f_dfo": dr.d_hat,
            "h1_amp": dr.amplitude[:, 0],
            "h2_amp": dr.amplitude[:, 1],
            "h1_true": np.full(n, true[0]),
            "h2_true": np.full(n, true[1]),
        }, []

    def state(self) -> DfoPartState:
        return DfoPartState(tuple(self.dfo.params.frequencies), self.dfo_state)

    def restore(self, state: object) -> None:
        if not isinstance(state, DfoPartState):
            raise ParameterError("state.parts.dfo", "a DfoPartState", type(state).__name__)
        self.retune(tuple(state.frequencies))
        self.dfo_state = state.dfo


def _check_band(base: tuple[float, ...], sample_time: float) -> None:
    """The DFO is designed at the base spindle speed: each harmonic below the Nyquist
    frequency of ``sample_time``, else the reason a user reads (the band it needs, the
    rate's Nyquist frequency, the rate it would take).

    Raises
    ------
    CutwatchError
        A harmonic at or above the Nyquist frequency.
    """
    nyq = 0.5 / sample_time
    if not base or max(base) < nyq:
        return
    hz = " and ".join(f"{f:g}" for f in base)
    raise CutwatchError(
        f"the DFO tracks the tooth-passing harmonics at {hz} Hz ({BASE_RPM:g} rpm), a band "
        f"up to {max(base):g} Hz; a {1 / sample_time:g} Hz source carries up to its Nyquist "
        f"frequency, {nyq:g} Hz: it needs a rate above {2 * max(base):g} Hz"
    )
