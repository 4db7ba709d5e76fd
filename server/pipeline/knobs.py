"""The live pipeline's knobs: one table of names, defaults and bounds, one check.

:data:`KNOB_TABLE` is the single source of every knob's default, range, unit and
choices; the REST request models read their bounds from it. :meth:`Knob.check` is the
one validation (one message per kind: ``true or false``, ``one of a, b``, ``a number in
[lo, hi] unit``), used by :class:`KnobValues` (the pipeline's current values) and by
anything else that must refuse a knob value the same way.

A :class:`Knob` is frozen: :meth:`KnobValues.knobs` hands out snapshots, so a caller
cannot change a knob behind the pipeline's back.

Each knob names the parts that read it (:attr:`Knob.parts`; :data:`SIMULATOR`: the
simulated stage and its scenario's script, read when the source is the simulator). A
pipeline offers the knobs of its own parts only
(:meth:`server.pipeline.live_pipeline.LivePipeline.knobs`): on the machining centre its
monitors' two (the spindle's and the axes'), not the stage's; a knob no part of the
pipeline reads is refused, naming the parts that would (:func:`not_read`). A part of the
pipeline that is paused (a band over the Nyquist frequency, a part it needs not running)
keeps its knobs: a value set then is stored and applies when it runs again
(:attr:`Knob.waiting` says so).

Each knob names the dashboard page it is set on (:attr:`Knob.page`, as a chart carries its
page): the operator's (the machine's tab: the process monitor's teach-in) or the research
tab (the default: the simulated stage's and the estimators' knobs).
"""

from __future__ import annotations

import math
from collections.abc import Collection, Iterator, Mapping
from dataclasses import dataclass, replace

from common.errors import ParameterError
from machine.effects import EFFECT_NAMES
from server.pipeline.eccentricity_part import FORCE_SOURCES, TUNERS
from server.pipeline.part import Page

#: spindle speed at which the force's frequencies are the papers' 100 / 200 Hz
BASE_RPM = 3000.0

#: a knob's value (one definition: the pipeline's knobs, the stream's messages and the
#: PATCH request all import it)
KnobValue = bool | float | str

#: the reader of the simulated stage's knobs (the pipeline itself, when its source is the
#: simulator: ``MeasurementSource.knobs_apply``), beside the parts' names
SIMULATOR = "simulator"
#: the readers that are not parts, in words
READERS = {
    SIMULATOR: "the simulated stage",
    "spindle_steps": "the periodic spindle steps of the stage's scenario script",
}


@dataclass(frozen=True)
class Knob:
    """One live parameter: its value (the default in :data:`KNOB_TABLE`) and its bounds.

    Attributes
    ----------
    name, value, unit, doc
        The knob, its value, its unit and a one-line description.
    min, max
        Closed bounds of a number (None: a flag or a choice).
    choices
        The allowed strings of a choice (None otherwise).
    parts
        The parts that read it (:data:`SIMULATOR`: the simulated stage); a pipeline's
        copy names only its own parts among them.
    waiting
        In a pipeline's copy: why none of its parts that read it runs now (the value is
        kept for when one does); ``""``: one runs.
    page
        The dashboard page it is set on: ``"operator"`` (the machine's tab, an operator's
        knob) or ``"research"``.
    """

    name: str
    value: KnobValue
    min: float | None
    max: float | None
    unit: str
    doc: str
    choices: tuple[str, ...] | None = None
    parts: tuple[str, ...] = ()
    waiting: str = ""
    page: Page = "research"

    @property
    def kind(self) -> str:
        """``"bool"``, ``"choice"`` or ``"number"``."""
        if isinstance(self.value, bool):
            return "bool"
        return "choice" if self.choices is not None else "number"

    @property
    def allowed(self) -> str:
        """What the knob accepts, in the words of every refusal."""
        if self.kind == "bool":
            return "true or false"
        if self.kind == "choice":
            return "one of " + ", ".join(self.choices or ())
        return f"a number in [{self.min:g}, {self.max:g}] {self.unit}".rstrip()

    def check(self, value: object) -> KnobValue:
        """The value as the knob holds it (a number as float).

        Raises
        ------
        ParameterError
            ``value`` is of the wrong type or outside the range (named by the knob).
        """
        if self.kind == "bool":
            if isinstance(value, bool):
                return value
        elif self.kind == "choice":
            if isinstance(value, str) and value in (self.choices or ()):
                return value
        elif isinstance(value, int | float) and not isinstance(value, bool):
            v = float(value)
            lo, hi = self.min, self.max
            if math.isfinite(v) and (lo is None or v >= lo) and (hi is None or v <= hi):
                return v
        raise ParameterError(self.name, self.allowed, value)


def _number(
    name: str,
    value: float,
    lo: float,
    hi: float,
    unit: str,
    doc: str,
    parts: tuple[str, ...],
    page: Page = "research",
) -> Knob:
    return Knob(name, value, lo, hi, unit, doc, parts=parts, page=page)


def _flag(name: str, value: bool, doc: str, parts: tuple[str, ...]) -> Knob:
    return Knob(name, value, None, None, "", doc, parts=parts)


def _choice(
    name: str, value: str, choices: tuple[str, ...], doc: str, parts: tuple[str, ...]
) -> Knob:
    return Knob(name, value, None, None, "", doc, choices=choices, parts=parts)


_SIM = (SIMULATOR,)
_ECC = ("eccentricity",)
#: the process monitor on the stage's program, the spindle's on the centre's power and the axes'
#: monitor on their process forces
_MONITORS = ("process", "spindle", "axis_monitor")


#: every knob with its default, bounds and doc (the single source of the bounds)
KNOB_TABLE: tuple[Knob, ...] = (
    _number(
        "spindle_rpm",
        BASE_RPM,
        600.0,
        6000.0,
        "rpm",
        "spindle speed (3000 rpm = the papers' 100/200 Hz force)",
        _SIM,
    ),
    _number("feed_scale", 1.0, 0.0, 3.0, "", "feed: scales the cutting force", _SIM),
    _flag("weight_on", False, "seed 000's weight on the load", _SIM),
    _number(
        "removal_rate",
        2.0,
        0.0,
        20.0,
        "%/s",
        "workpiece mass removed per second (default scenario)",
        ("workpiece",),
    ),
    _flag(
        "spindle_changes",
        True,
        "spindle steps to 80 % every 15 s (default scenario)",
        ("spindle_steps",),  # the script's periodic steps (server/pipeline/scenarios.py)
    ),
    _number("current_noise", 0.0, 0.0, 0.05, "A", "rms noise of the current measurement", _SIM),
    _number(
        "wear_rate",
        0.5,
        0.05,
        5.0,
        "min/s",
        "minutes of tool wear per second of machining (default scenario)",
        ("wear",),
    ),
    _number(
        "eccentricity_um",
        20.0,
        0.0,
        50.0,
        "um",
        "tool eccentricity radius (default scenario; seed 003 case 1: 20 um)",
        _ECC,
    ),
    _number("eccentricity_deg", 40.0, 0.0, 360.0, "deg", "tool eccentricity angle", _ECC),
    _flag("esc_on", True, "eccentricity cancellation (tuner) running", _ECC),
    _choice(
        "tuner",
        "esc",
        TUNERS,
        "tuner: extremum seeking (seed 003, Table 1 gains: converges from the default "
        "40 deg; stalls for phases far from its start, e.g. 90-270 deg) or fast "
        "(converges from any phase in ~5 revolutions)",
        _ECC,
    ),
    _choice(
        "ecc_force",
        "dynamometer",
        FORCE_SOURCES,
        "tuner's force: dynamometer, seed-000 observers (fixed mass) or adaptive "
        "observers (mass identified at spindle order 4.125)",
        _ECC,
    ),
    _number("ecc_mass_error", 0.0, -10.0, 10.0, "%", "observers' nominal mass error", _ECC),
    # the process monitor (issue 21, server/pipeline/process_part.py) and the spindle's
    # monitor on the centre's cutting power (server/pipeline/spindle_part.py)
    _number(
        "teach_parts",
        5.0,
        1.0,
        50.0,
        "parts",
        "process monitor: good parts taught per (tool, program, block) before it watches; "
        "a new value restarts the teach-in of every block",
        _MONITORS,
        page="operator",  # the operator's teach-in: on the machine's tab
    ),
    _number(
        "band_factor",
        4.0,
        1.0,
        20.0,
        "",
        "process monitor: half-width of the bands on the mean force in taught spreads "
        "(at least band_rel 15 % of the mean); applies from the next sample, no relearn",
        _MONITORS,
        page="operator",
    ),
    # each plant effect the observers do not model (machine.effects), on/off
    *(_flag(f"effect_{e}", False, f"plant effect {e!r} (unmodelled)", _SIM) for e in EFFECT_NAMES),
)

#: name -> knob with its default value
KNOBS: Mapping[str, Knob] = {k.name: k for k in KNOB_TABLE}


class KnobValues(Mapping[str, KnobValue]):
    """The current value of every knob; read like a dict, changed only by :meth:`set`.

    Parameters
    ----------
    overrides
        Values that differ from the table's defaults (a scenario's own), checked.
    """

    def __init__(self, overrides: Mapping[str, object] | None = None) -> None:
        self._values: dict[str, KnobValue] = {k.name: k.value for k in KNOB_TABLE}
        for name, value in (overrides or {}).items():
            self.set(name, value)

    def __getitem__(self, name: str) -> KnobValue:
        return self._values[name]

    def __iter__(self) -> Iterator[str]:
        return iter(self._values)

    def __len__(self) -> int:
        return len(self._values)

    def number(self, name: str) -> float:
        """A number knob's value as float."""
        return float(self._values[name])

    def set(self, name: str, value: object) -> None:
        """Set one knob; nothing changes on error.

        Raises
        ------
        ParameterError
            Unknown name (field ``name``), wrong type or a value out of range (field: the
            knob's name).
        """
        if name not in KNOBS:
            raise ParameterError("name", f"one of {sorted(KNOBS)}", name)
        self._values[name] = KNOBS[name].check(value)

    def update(self, changes: Mapping[str, object]) -> None:
        """Set several knobs, all or nothing (every value checked before any is set).

        Raises
        ------
        ParameterError
            The first refused change.
        """
        clean: dict[str, KnobValue] = {}
        for name, value in changes.items():
            if name not in KNOBS:
                raise ParameterError("name", f"one of {sorted(KNOBS)}", name)
            clean[name] = KNOBS[name].check(value)
        self._values.update(clean)

    def knobs(self) -> dict[str, Knob]:
        """Every knob with its current value (frozen copies)."""
        return {name: replace(KNOBS[name], value=v) for name, v in self._values.items()}

    def as_dict(self) -> dict[str, KnobValue]:
        """Name -> current value (a copy)."""
        return dict(self._values)


def not_read(name: str, offered: Collection[str]) -> tuple[str, str]:
    """Why a knob of the table is refused by a pipeline whose parts read only ``offered``:
    (what is expected, the sentence naming the parts that would read ``name``)."""
    expected = (
        "one of the knobs this pipeline's parts read: " + ", ".join(offered)
        if offered
        else "no knob: no part this pipeline runs reads one (a feed's parts are built "
        "once its machine is described)"
    )
    readers = list(KNOBS[name].parts)
    if readers[0] in READERS and len(readers) == 1:
        who = READERS[readers[0]]
    elif len(readers) == 1:
        who = f"the {readers[0]} part"
    else:
        who = f"the {', '.join(readers[:-1])} and {readers[-1]} parts"
    return expected, f"{name} is read by {who}, which this pipeline does not run"
