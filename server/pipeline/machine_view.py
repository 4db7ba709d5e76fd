"""What the source delivers, as the live parts see it: the one place a machine is described.

A part asks the machine view whether it can run (``Part.requires``,
:mod:`server.pipeline.part`): which axes the source hands out (each ``rigid`` or
``two_inertia``, with the roles of its signals: ``q_m``, ``q_l``, ``tau_m``, ``i_m``,
``f_ext``...), the spindle's signals, the program's identities, the sample rate, the
spindle speed (when known), whether the truth travels beside them and whether the
machine is simulated (the scenario's knobs drive it). The live pipeline builds the view
from its source (:meth:`MachineView.of`) and builds it again when the spindle speed
changes; a part whose requirement stops holding pauses with the reason.

The view is read from the machine description (``common/machine.schema.json``,
:class:`common.machine_description.MachineDescription`: a broker feed's meta, a log's
sidecar) when the source has one (its ``description``), else it is the one two-inertia
axis of the simulated stage (:data:`SIGNALS`). It is small and read-only on purpose:
the parts never look at a source or a description themselves.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import Any

from common.machine_description import AxisDescription, MachineDescription
from server.pipeline.sources import NOMINAL, MeasurementSource

__all__ = ["SIGNALS", "AxisView", "MachineView", "description_of", "has_prior"]

#: the signals of the simulated stage's one axis (two-inertia, with its reference force)
SIGNALS = frozenset({"tau_m", "i_m", "q_m", "q_l", "f_ext"})


@dataclass(frozen=True)
class AxisView:
    """One feed axis as the parts see it: its name, kind, the roles of its signals, and
    whether its nominal holds every two-inertia parameter (``prior``: the simulator's
    and a replayed log's do; a feed's only when its description gives them)."""

    name: str
    kind: str
    roles: frozenset[str]
    prior: bool = True

    def has(self, *roles: str) -> bool:
        return all(r in self.roles for r in roles)


@dataclass(frozen=True)
class MachineView:
    """What a machine's source delivers (see the module docstring).

    Attributes
    ----------
    source
        The source's name (``simulator``, ``replay``, ``mqtt``...).
    sample_time
        [s].
    axes
        The feed axes, in order.
    spindle
        The roles of the spindle's signals (``speed``, ``power``...; empty: none).
    identities
        The program's identities the source delivers (``program``, ``tool``...).
    spindle_rpm
        The spindle speed in effect [rpm]; NaN when not known.
    has_truth
        The simulator's truth travels beside the measurements.
    simulated
        The machine is simulated: the scenario's knobs drive it (its parts may simulate
        beside it).
    """

    source: str
    sample_time: float
    axes: tuple[AxisView, ...]
    spindle: frozenset[str] = frozenset()
    identities: frozenset[str] = frozenset()
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

    @property
    def kind(self) -> str:
        """The first axis' kind (``""``: no axis)."""
        return self.axes[0].kind if self.axes else ""

    @property
    def signals(self) -> frozenset[str]:
        """Every signal by name: the roles of the axes' signals, ``spindle.<role>``, and
        the identities."""
        out = {r for a in self.axes for r in a.roles}
        out |= {f"spindle.{r}" for r in self.spindle} | set(self.identities)
        return frozenset(out)

    def lacks(self, *names: str) -> tuple[str, ...]:
        """Those of ``names`` the source does not deliver."""
        have = self.signals
        return tuple(n for n in names if n not in have)

    def axes_with(self, *roles: str, kind: str | None = None) -> tuple[AxisView, ...]:
        """The axes that carry every one of ``roles`` (and are of ``kind``, if given)."""
        return tuple(a for a in self.axes if a.has(*roles) and kind in (None, a.kind))

    def with_spindle(self, rpm: float) -> MachineView:
        """The same machine at spindle speed ``rpm``."""
        if rpm == self.spindle_rpm:
            return self
        return replace(self, spindle_rpm=float(rpm))

    @classmethod
    def of(cls, source: MeasurementSource, spindle_rpm: float = math.nan) -> MachineView:
        """The view of ``source``: from its machine description when it has one (a feed's
        meta, a log's sidecar), else the simulated stage's one axis."""
        desc = description_of(source)
        if desc is None:
            axes: tuple[AxisView, ...] = (AxisView("X", source.kind, SIGNALS),)
            spindle: frozenset[str] = frozenset()
            idents: frozenset[str] = frozenset()
        else:
            axes = tuple(
                AxisView(a.name, a.kind, frozenset(a.signals), has_prior(a)) for a in desc.axes
            )
            spindle = frozenset(desc.spindle.signals) if desc.spindle is not None else frozenset()
            idents = frozenset(desc.identities)
        return cls(
            source=source.name,
            sample_time=float(source.sample_time),
            axes=axes,
            spindle=spindle,
            identities=idents,
            spindle_rpm=float(spindle_rpm),
            has_truth=bool(source.has_truth),
            simulated=bool(source.knobs_apply),
        )


def has_prior(ax: AxisDescription) -> bool:
    """The axis' nominal gives every two-inertia parameter (K_t its own key or the nominal's)."""
    have = set(ax.nominal) | ({"K_t"} if ax.K_t is not None else set())
    return all(k in have for k in NOMINAL)


def description_of(source: Any) -> MachineDescription | None:
    """The machine description a source carries (a feed's, a log's), if any."""
    for obj in (source, getattr(source, "feed", None), getattr(source, "log", None)):
        for attr in ("description", "machine"):
            try:
                d = getattr(obj, attr, None)
            except Exception:  # a log whose older sidecar describes no machine
                d = None
            if isinstance(d, MachineDescription):
                return d
    return None
