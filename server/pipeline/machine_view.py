"""What the source delivers, as the live parts see it: the one place a machine is described.

A part asks the machine view whether it can run (``Part.requires``,
:mod:`server.pipeline.part`): which signals the source hands out, at which sample rate,
at which spindle speed (when known), whether the truth travels beside them and whether
the machine is simulated (the scenario's knobs drive it). The live pipeline builds the
view from its source (:meth:`MachineView.of`) and builds it again when the spindle speed
changes; a part whose requirement stops holding pauses with the reason.

The view is small and read-only on purpose: the machine description the real-axis work
defines (a JSON Schema of axes with their kind and signal columns, a spindle, the
program identities, one sample rate) produces it through :meth:`MachineView.of`, and the
parts never look at a source themselves.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from server.pipeline.sources import MeasurementSource

__all__ = ["SIGNALS", "MachineView"]

#: the signals of a two-inertia axis with its reference force, as the simulator has them
SIGNALS = frozenset({"t", "tau_m", "i_m", "q_m", "q_l", "f_ext"})


@dataclass(frozen=True)
class MachineView:
    """What a machine's source delivers (see the module docstring).

    Attributes
    ----------
    source
        The source's name (``simulator``, ``replay``, ``mqtt``...).
    kind
        ``two_inertia`` (motor and load positions) or ``rigid`` (motor only).
    signals
        The signal columns each block carries (``t``, ``tau_m``, ``i_m``, ``q_m``,
        ``q_l``, ``f_ext``...).
    sample_time
        [s].
    spindle_rpm
        The spindle speed in effect [rpm]; NaN when the source does not say.
    has_truth
        The simulator's truth travels beside the measurements.
    simulated
        The machine is simulated: the scenario's knobs drive it (its parts may simulate
        beside it).
    """

    source: str
    kind: str
    signals: frozenset[str]
    sample_time: float
    spindle_rpm: float = math.nan
    has_truth: bool = False
    simulated: bool = False

    @property
    def sample_rate(self) -> float:
        """[Hz]."""
        return 1.0 / self.sample_time

    @property
    def nyquist(self) -> float:
        """Half the sample rate [Hz]: the highest frequency the signals can carry."""
        return 0.5 / self.sample_time

    def lacks(self, *names: str) -> tuple[str, ...]:
        """Those of ``names`` the source does not deliver."""
        return tuple(n for n in names if n not in self.signals)

    def with_spindle(self, rpm: float) -> MachineView:
        """The same machine at spindle speed ``rpm``."""
        if rpm == self.spindle_rpm:
            return self
        from dataclasses import replace

        return replace(self, spindle_rpm=float(rpm))

    @classmethod
    def of(cls, source: MeasurementSource, spindle_rpm: float = math.nan) -> MachineView:
        """The view of ``source``: its own ``signals`` when it lists them (a live feed's
        meta), else a two-inertia axis' (:data:`SIGNALS`)."""
        signals = getattr(source, "signals", None)
        return cls(
            source=source.name,
            kind=source.kind,
            signals=frozenset(signals) if signals is not None else SIGNALS,
            sample_time=float(source.sample_time),
            spindle_rpm=float(spindle_rpm),
            has_truth=bool(source.has_truth),
            simulated=bool(source.knobs_apply),
        )
