"""The identified observer effects as a live part (issue 4 section 4, the residual loop).

:class:`EffectsPart` subtracts the terms of the effects the residual loop identified
(:mod:`estimators.observer_effects`: friction asymmetry, cogging, screw lead error...)
from the stage's fixed-parameter observer force, as
:mod:`estimators.residual.two_inertia` does: channel ``f_effects``. With no effect
installed it repeats ``f_fixed``. ``POST /api/observer-effects`` installs them
(:meth:`EffectsPart.install`); they start from their initial state, and after a break in
the measurements their filters start again.
"""

from __future__ import annotations

from dataclasses import dataclass

from common.errors import ParameterError
from estimators.observer_effects import (
    EffectsParams,
    EffectsState,
    ObserverEffect,
    ObserverEffects,
)
from server.pipeline.part import Block, Channel, LivePart, Outputs
from server.pipeline.stage_part import COLORS, FORCE, StagePart

__all__ = ["EffectsPart", "EffectsPartState"]


@dataclass
class EffectsPartState:
    """The effects installed and their filters' state (None: none installed)."""

    effects: tuple[ObserverEffect, ...]
    filters: EffectsState | None


class EffectsPart(LivePart):
    """The fixed-parameter observer with the identified effects (module docstring)."""

    name = "effects"
    needs = ("stage",)
    channels = FORCE.series(
        Channel(
            "f_effects",
            "N m",
            "fixed observer with the identified effects",
            "force",
            color=COLORS["effects"],
            role="with_effects",
            legend="fixed + identified effects",
        ),
        start=6,
    )

    def __init__(self, stage: StagePart, effects: tuple[ObserverEffect, ...] = ()) -> None:
        self._params = stage.run.front.params
        self.fx: ObserverEffects | None = None
        self.effects: tuple[ObserverEffect, ...] = ()
        self.install(effects)

    def install(self, effects: tuple[ObserverEffect, ...]) -> None:
        """Install ``effects`` (``()`` removes them), from their initial state.

        Raises
        ------
        ParameterError
            An effect without its fitted coefficients.
        """
        fp = self._params
        effects = tuple(effects)
        fx = None
        if effects:
            fx = ObserverEffects(EffectsParams(effects, fp.sample_time, fp.q_hz, fp.q_order))
            self.fx_state = fx.initial_state()
        self.fx, self.effects = fx, effects

    def step(self, block: Block) -> Outputs:
        b = block.shared["stage"]
        if self.fx is None:
            return {"f_effects": b.f_fixed}, []
        if block.discontinuity is not None:
            self.fx_state = self.fx.initial_state()
        m = b.meas
        # the effects' terms, at t_(k-1) like the observer's (estimators.observer_effects)
        self.fx_state, er = self.fx.step(self.fx_state, b.alpha, m.t, m.q_m, m.q_l, m.tau_m)
        return {"f_effects": b.f_fixed - er.f_corr}, []

    def state(self) -> EffectsPartState:
        return EffectsPartState(self.effects, self.fx_state if self.fx is not None else None)

    def restore(self, state: object) -> None:
        if not isinstance(state, EffectsPartState):
            raise ParameterError("state.parts.effects", "an EffectsPartState", type(state).__name__)
        if (state.filters is None) != (not state.effects):
            raise ParameterError(
                "state.parts.effects",
                "the effects' filters with the effects",
                "one without the other",
            )
        self.install(state.effects)
        if state.filters is not None:
            self.fx_state = state.filters
