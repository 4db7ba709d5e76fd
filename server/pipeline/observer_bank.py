"""The observer bank of the live pipeline: every estimator that runs on the source's
measurements, advanced together block by block.

- :class:`~server.pipeline.stage_run.StageRun`: the fixed-parameter, adaptive (RLS) and
  switching-RLS force observers and the gated segment identifier;
- seed 002's harmonic observer (DFO) through Q(s) (:mod:`server.pipeline.stage_harmonics`),
  on the observer with the gated segment identifier's parameters: on the fixed one the
  workpiece's unmodelled inertia biases the harmonics (measured: 2.8 N m for a true
  4.0); on the adaptive (RLS) one its J_L moves at every spindle step and the 100 Hz
  acceleration times that error reads as a harmonic (measured, 100 s of the default
  scenario: amplitude error median 9 % / p90 46 %, and after 5 of 6 spindle steps not
  within 5 % in 2 s; on the segment parameters: 0.8 % / 3 %, within 5 % 40-65 ms after
  every step); retuned, state kept, when the spindle speed changes;
- the identified observer effects (:mod:`estimators.observer_effects`), subtracted from
  the fixed-parameter observer's force (channel ``f_effects``).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

from common.arrays import F64
from common.errors import ParameterError
from estimators.dfo import Dfo, DfoRecord, DfoState
from estimators.observer_effects import (
    EffectsParams,
    EffectsState,
    ObserverEffect,
    ObserverEffects,
)
from estimators.rls import IdentifierParams
from server.pipeline.sources import MeasurementSource, SourceBlock
from server.pipeline.stage_harmonics import make_dfo
from server.pipeline.stage_run import StageBlock, StageRun, StageRunState


@dataclass
class BankState:
    """The bank's estimators' state (checkpointed)."""

    run: StageRunState
    dfo_frequencies: tuple[float, ...]
    dfo: DfoState
    effects: EffectsState | None


@dataclass(frozen=True)
class BankBlock:
    """One block of the bank: the stage observers', the DFO's and the effects' outputs."""

    stage: StageBlock
    dfo: DfoRecord
    f_effects: F64


class ObserverBank:
    """Every estimator on the measurements (see the module docstring).

    Parameters
    ----------
    source
        The measurement source (its nominal parameters and sample time build the
        observers).
    ident, design
        The identifiers' parameters and the observer's design options.
    frequencies
        The harmonic observer's first frequencies [Hz] (retuned by :meth:`retune`).
    effects
        Identified observer effects to install (``()``: none).
    """

    def __init__(
        self,
        source: MeasurementSource,
        ident: IdentifierParams,
        design: Mapping[str, Any],
        frequencies: tuple[float, ...],
        effects: tuple[ObserverEffect, ...] = (),
    ) -> None:
        self.run = StageRun(source=source, ident=ident, observer_design=dict(design))
        self.dfo = Dfo(make_dfo(self.run.front.params, tuple(frequencies)))
        self.dfo_state = self.dfo.initial_state()
        self.fx: ObserverEffects | None = None
        self.effects: tuple[ObserverEffect, ...] = ()
        self.set_effects(effects)

    def retune(self, frequencies: tuple[float, ...]) -> None:
        """The harmonic observer on new frequencies (its state kept)."""
        if frequencies != tuple(self.dfo.params.frequencies):
            self.dfo = Dfo(self.dfo.params.with_frequencies(frequencies))

    def set_effects(self, effects: tuple[ObserverEffect, ...]) -> None:
        """Install identified effects (``()`` removes them), from their initial state.

        Raises
        ------
        ParameterError
            An effect without its fitted coefficients.
        """
        fp = self.run.front.params
        effects = tuple(effects)
        fx = None
        if effects:
            fx = ObserverEffects(EffectsParams(effects, fp.sample_time, fp.q_hz, fp.q_order))
            self.fx_state = fx.initial_state()
        self.fx, self.effects = fx, effects

    def reset(self) -> None:
        """Every estimator back to its initial state (the DFO's frequencies kept)."""
        self.run.reset_estimators()
        self.dfo_state = self.dfo.initial_state()
        if self.fx is not None:
            self.fx_state = self.fx.initial_state()

    def state(self) -> BankState:
        """Every estimator's state now (shares the arrays: copy it to keep it)."""
        fx = self.fx_state if self.fx is not None else None
        return BankState(self.run.state(), tuple(self.dfo.params.frequencies), self.dfo_state, fx)

    def restore(self, st: BankState) -> None:
        """Continue from ``st`` (the effects of the state installed first).

        Raises
        ------
        ParameterError
            The state's effects' state without installed effects, or the reverse.
        """
        if (st.effects is None) != (self.fx is None):
            raise ParameterError(
                "effects", "the state's effects installed", "effects state mismatch"
            )
        self.run.restore(st.run)
        self.retune(tuple(st.dfo_frequencies))
        self.dfo_state = st.dfo
        if st.effects is not None:
            self.fx_state = st.effects

    def restart_filters(self, t: float) -> None:
        """The measurements resume after a break (:meth:`StageRun.restart_filters`): the
        stage's filters restart, its estimates go on; the harmonic observer (whose
        phases the break loses) and the effects' filters start again."""
        self.run.restart_filters(t)
        self.dfo_state = self.dfo.initial_state()
        if self.fx is not None:
            self.fx_state = self.fx.initial_state()

    def process(self, block: SourceBlock) -> BankBlock:
        """Run every estimator on one non-empty block."""
        b = self.run.process(block)
        self.dfo_state, dr = self.dfo.step(self.dfo_state, b.f_segment)
        f_effects = b.f_fixed
        if self.fx is not None:
            m = b.meas
            # the effects' terms, at t_(k-1) like the observer's (estimators.observer_effects)
            self.fx_state, er = self.fx.step(self.fx_state, b.alpha, m.t, m.q_m, m.q_l, m.tau_m)
            f_effects = b.f_fixed - er.f_corr
        return BankBlock(b, dr, f_effects)
