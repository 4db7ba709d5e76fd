"""Pipeline wiring for the live service: the simulated stage feeding every force observer.

The public surface is the contract the live service builds on:

- ``LivePipeline(scenario: str = "default", seed: int = 0, source=None)``; a log replay
  is ``LivePipeline.from_log(path)``
- ``.sample_time`` (s), ``.t`` (time of the source, s), ``.finished`` (a log has ended)
- ``.channels() -> list[Channel]``: every per-sample output, with unit and group
- ``.step(n) -> dict[str, np.ndarray]``: advance ``n`` samples; one float64 array of
  length ``n`` per channel name (plus ``"t"``)
- ``.knobs() -> dict[str, Knob]``: live-tweakable parameters with their ranges
- ``.set_knob(name, value)``: validated; raises ``ParameterError`` naming the field, the
  allowed range and the value; nothing changes on error
- ``.reset()``; ``.snapshot() -> dict`` (latest values, truths, knob values, accuracy)
- ``.accuracy() -> dict``: rolling rms of each force estimate over 1 s and 10 s
  (:mod:`server.pipeline.accuracy`)
- ``SCENARIOS``: name -> one-line description

Behind it is :class:`server.pipeline.stage_run.StageRun`: a measurement source
(:mod:`server.pipeline.sources`; by default the simulated two-inertia stage of seed 000,
or a replayed log, or a live feed) with the fixed-parameter, adaptive (ordinary RLS) and
switching-RLS force observers. The estimators see the Measurements only; the truth
columns are for display (NaN, but for the reference force, from a source without Truth).
A source's block marked as a discontinuity resets every observer before it is run; a
block of no samples changes nothing.

Scenario events are scheduled on simulated time, so a run is the same whatever the
wall-clock speed. The default scenario: the stage reciprocates while milling; the
workpiece (an inertia of the size of seed 000's added weight) loses mass at
``removal_rate`` % per second until a fresh blank is clamped; every 15 s the spindle
speed steps between the knob's value and 80 % of it (force gain and frequencies, as in
seed 001 Fig. 9).

Identification you can trust (issue 13, ``docs/live-identification.md``): the gated
segment identifier (:mod:`estimators.segment_id`) streams J_L, B_L, F_CL with 95 %
interval bounds and an excited flag (channels ``<p>_seg``, ``<p>_lo``, ``<p>_hi``,
``<p>_excited``). The pipeline tells it what the CNC knows: a spindle step and a tool
change change the cutting force's DC (the reversal segment around them is discarded), a
fresh workpiece changes J_L (it restarts). The wear grows the force smoothly (no steps
at pass boundaries, which fall on the reversals), and a fresh blank is clamped just before
a reversal (the table at its stroke end), not in the middle of a stroke.
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass, replace

import numpy as np

from estimators import dfo as dfo_mod
from estimators.errors import ParameterError
from estimators.observer_effects import EffectsParams, ObserverEffect, ObserverEffects
from estimators.rls import IdentifierParams
from machine.effects import EFFECT_NAMES, PlantEffects
from machine.params import ADDED_WEIGHT_INERTIA, preset
from machine.stage import SEED000_FORCE, SEED001_FORCE, CuttingForce, StageConfig
from server.pipeline.accuracy import RollingAccuracy
from server.pipeline.eccentricity_part import (
    ECC_BASE_RPM,
    ECC_CHANNELS,
    FORCE_SOURCES,
    TUNERS,
    LiveEccentricity,
)
from server.pipeline.sources import (
    MeasurementSource,
    ReplaySource,
    SimulatorSource,
    SourceBlock,
    open_replay,
)
from server.pipeline.stage_harmonics import make_dfo
from server.pipeline.stage_run import StageRun
from server.pipeline.wear_clock import AcceleratedToolWear


@dataclass(frozen=True)
class Channel:
    name: str
    unit: str
    group: str
    label: str


@dataclass
class Knob:
    name: str
    value: float | bool | str
    min: float | None
    max: float | None
    unit: str
    doc: str
    choices: tuple[str, ...] | None = None


SCENARIOS: dict[str, str] = {
    "default": "X stage reciprocating while milling; workpiece losing mass; spindle changes",
    "seed000-weight": "seed 000 Table III: the weight (+2.92e-4 kg m^2) added at 10 s",
    "seed001-spindle": "seed 001 Fig. 9: spindle speed and force drop to 80 % at 11 s",
}

#: spindle speed at which the force's frequencies are the papers' 100 / 200 Hz
BASE_RPM = 3000.0
SPINDLE_PERIOD = 15.0  # default scenario: the spindle steps every 15 s of simulated time
WORKPIECE_INERTIA = ADDED_WEIGHT_INERTIA  # a blank as heavy as seed 000's weight
REMOVAL_STEP = 0.05  # the workpiece's inertia is updated in steps of 5 % of the blank
PASS_S = 1.0  # default scenario: one tool-wear pass per second of simulated time
#: the wear clock of the first tool starts once the observers have settled (their first
#: second reads ~3 % low, which biased the monitor's sharp-tool force, seed004 (25), and with
#: it every later VB by ~+0.03 mm); later tools start at once (observers settled)
WEAR_WARMUP_S = 5.0
VB_LIMIT = 0.3  # flank wear at which the tool is changed [mm] (seed 004's limit)
#: a fresh blank is clamped this long before a reversal's centre (the table near its
#: stroke end; the reversal right after it identifies the new J_L)
CLAMP_BEFORE_REVERSAL = 0.3
#: ... at the last such reversal before the blank is used up: the clamp is planned this
#: many seconds of removal ahead (two strokes). Waiting for a reversal with the blank
#: used up held J_L while the identifier extrapolated its fall (measured: J_L 10 % low
#: after 8 s, the DFO's amplitudes 6-8 % low)
CLAMP_LOOKAHEAD = 8.0

CHANNELS: list[Channel] = [
    Channel("f_true", "N m", "force", "true cutting torque"),
    Channel("f_fixed", "N m", "force", "fixed-parameter observer"),
    Channel("f_adaptive", "N m", "force", "adaptive observer (RLS)"),
    Channel("f_switching", "N m", "force", "switching-RLS observer"),
    Channel("f_segment", "N m", "force", "observer on the gated segment identifier"),
    Channel("J_L_true", "kg m^2", "J_L", "true J_L"),
    Channel("J_L_adaptive", "kg m^2", "J_L", "J_L identified (RLS)"),
    Channel("J_L_switching", "kg m^2", "J_L", "J_L identified (switching RLS)"),
    Channel("B_L_true", "N m s/rad", "B_L", "true B_L"),
    Channel("B_L_adaptive", "N m s/rad", "B_L", "B_L identified (RLS)"),
    Channel("B_L_switching", "N m s/rad", "B_L", "B_L identified (switching RLS)"),
    Channel("F_CL_true", "N m", "F_CL", "true F_CL"),
    Channel("F_CL_adaptive", "N m", "F_CL", "F_CL identified (RLS)"),
    Channel("F_CL_switching", "N m", "F_CL", "F_CL identified (switching RLS)"),
    Channel("f_effects", "N m", "force", "fixed observer with the identified effects"),
    Channel("f_dfo", "N m", "force", "harmonic observer (DFO) on the segment observer"),
    Channel("h1_amp", "N m", "harmonics", "1st tooth-passing harmonic, DFO amplitude"),
    Channel("h2_amp", "N m", "harmonics", "2nd tooth-passing harmonic, DFO amplitude"),
    Channel("h1_true", "N m", "harmonics", "1st harmonic, true amplitude"),
    Channel("h2_true", "N m", "harmonics", "2nd harmonic, true amplitude"),
    Channel("vb_true", "mm", "wear", "flank wear, true"),
    Channel("vb_est", "mm", "wear", "flank wear, estimated from the adaptive observer"),
    Channel("vb_limit", "mm", "wear", "flank-wear limit (tool change)"),
    Channel("life_left", "min", "wear", "remaining tool life (wear clock)"),
    *(
        Channel(f"{q}_{suffix}", unit, q, f"{q} {what}")
        for q, unit in (("J_L", "kg m^2"), ("B_L", "N m s/rad"), ("F_CL", "N m"))
        for suffix, what in (
            ("seg", "identified (gated segments)"),
            ("lo", "95 % interval, lower bound"),
            ("hi", "95 % interval, upper bound"),
            ("excited", "excited (1) or not determined by the data (0)"),
        )
    ),
    Channel("mode_switching", "", "rls", "switching-RLS regressor mode"),
    Channel("excitation", "", "rls", "excitation index of the block"),
    Channel("omega_l", "rad/s", "motion", "load velocity (true)"),
    Channel("spindle_rpm", "rpm", "motion", "spindle speed in effect"),
    Channel("q_m", "rad", "motion", "motor angle (encoder)"),
    Channel("x_l", "m", "motion", "table position (load encoder x 10 mm lead)"),
] + [Channel(k, u, "eccentricity", lab) for k, (u, lab) in ECC_CHANNELS.items()]
SCREW_LEAD = 0.01  # m per revolution, for the displayed table position (papers give none)
#: the force estimates scored by the accuracy panel: every force channel but the truth
FORCE_ESTIMATES = tuple(c.name for c in CHANNELS if c.group == "force" and c.name != "f_true")


def _knobs() -> dict[str, Knob]:
    ks = [
        Knob(
            "spindle_rpm",
            BASE_RPM,
            600.0,
            6000.0,
            "rpm",
            "spindle speed (3000 rpm = the papers' 100/200 Hz force)",
        ),
        Knob("feed_scale", 1.0, 0.0, 3.0, "", "feed: scales the cutting force"),
        Knob("weight_on", False, None, None, "", "seed 000's weight on the load"),
        Knob(
            "removal_rate",
            2.0,
            0.0,
            20.0,
            "%/s",
            "workpiece mass removed per second (default scenario)",
        ),
        Knob(
            "spindle_changes",
            True,
            None,
            None,
            "",
            "spindle steps to 80 % every 15 s (default scenario)",
        ),
        Knob("current_noise", 0.0, 0.0, 0.05, "A", "rms noise of the current measurement"),
        Knob(
            "wear_rate",
            0.5,
            0.05,
            5.0,
            "min/s",
            "minutes of tool wear per second of machining (default scenario)",
        ),
        Knob(
            "eccentricity_um",
            20.0,
            0.0,
            50.0,
            "um",
            "tool eccentricity radius (default scenario; seed 003 case 1: 20 um)",
        ),
        Knob("eccentricity_deg", 40.0, 0.0, 360.0, "deg", "tool eccentricity angle"),
        Knob("esc_on", True, None, None, "", "eccentricity cancellation (tuner) running"),
        Knob(
            "tuner",
            "esc",
            None,
            None,
            "",
            "tuner: extremum seeking (seed 003, Table 1 gains: converges from the default "
            "40 deg; stalls for phases far from its start, e.g. 90-270 deg) or fast "
            "(converges from any phase in ~5 revolutions)",
            choices=TUNERS,
        ),
        Knob(
            "ecc_force",
            "dynamometer",
            None,
            None,
            "",
            "tuner's force: dynamometer, seed-000 observers (fixed mass) or adaptive "
            "observers (mass identified at spindle order 4.125)",
            choices=FORCE_SOURCES,
        ),
        Knob("ecc_mass_error", 0.0, -10.0, 10.0, "%", "observers' nominal mass error"),
    ]
    # each plant effect the observers do not model (machine.effects), on/off
    ks += [
        Knob(f"effect_{e}", False, None, None, "", f"plant effect {e!r} (unmodelled)")
        for e in EFFECT_NAMES
    ]
    return {k.name: k for k in ks}


class LivePipeline:
    """The stage and its observers, advanced block by block, with live knobs.

    Parameters
    ----------
    scenario
        One of :data:`SCENARIOS`, when the source is a simulation.
    seed
        Seed of the simulation's random generator.
    source
        Where the measurements come from (:mod:`server.pipeline.sources`). Default: the
        simulator of ``scenario``. A source the knobs do not apply to (a log, a live
        feed) runs with its own name as the scenario (``"replay"``) and the observers
        built from its nominal parameters.
    """

    def __init__(
        self, scenario: str = "default", seed: int = 0, source: MeasurementSource | None = None
    ) -> None:
        if source is not None and not source.knobs_apply:
            scenario = source.name
        elif scenario not in SCENARIOS:
            raise ParameterError("scenario", f"one of {sorted(SCENARIOS)}", scenario)
        self.scenario = scenario
        self.seed = seed
        self._knobs = _knobs()
        self.effects: tuple[ObserverEffect, ...] = ()
        if scenario == "seed001-spindle":
            self._knobs["spindle_changes"].value = False
        cfg, self._ident, self._design = self._base(source)
        self._force0: CuttingForce = cfg.force
        self.source = source or SimulatorSource(cfg, seed=seed)
        self.reset()

    @classmethod
    def from_log(cls, path: str | os.PathLike[str], seed: int = 0) -> LivePipeline:
        """The live observers fed by a measured log (:func:`server.pipeline.sources.open_replay`
        checks it); ``finished`` turns true at its last sample.

        Raises
        ------
        LogFormatError, CutwatchError
            The log is missing, unreadable or not a two-inertia log with its nominal
            parameters.
        """
        return cls(seed=seed, source=ReplaySource(open_replay(path)))

    # ------------------------------------------------------------------ set-up
    def _base(
        self, source: MeasurementSource | None
    ) -> tuple[StageConfig, IdentifierParams, dict[str, float]]:
        """The scenario's stage, identifier and observer design; for a given source, its
        sample time and the default design (the stage configuration then only gives the
        nominal cutting force: the harmonic observer's frequencies)."""
        if source is not None:
            ts = source.sample_time
            return StageConfig(force=SEED000_FORCE), IdentifierParams(sample_time=ts), {}
        if self.scenario == "seed001-spindle":
            p = preset("seed001")
            ident = IdentifierParams(q_rls_hz=40.0, scale=(p.J_L, p.B_L, p.F_CL, 1.0))
            design = {"err3_J_M": 0.0, "err3_B_M": 0.0, "err3_K": 0.0, "err3_F_CM": 0.0}
            return StageConfig(params=p, force=SEED001_FORCE), ident, design
        return StageConfig(params=preset("seed000"), force=SEED000_FORCE), IdentifierParams(), {}

    def reset(self) -> None:
        """Start the source (the simulation from t = 0, a log from its first sample) and
        every estimator again (knobs kept)."""
        self.source.reset()
        self.run = StageRun(source=self.source, ident=self._ident, observer_design=self._design)
        self.sample_time = float(self.source.sample_time)
        self.last_block: SourceBlock | None = None
        self._removed = 0.0  # fraction of the current workpiece removed
        self._removed_applied = 0.0  # the removal the plant has (steps, mid-stroke)
        self._clamp_pending = False  # the blank is nearly used up; a fresh one is due
        self._pending_since = 0.0
        self._weight = math.nan  # seed 000's weight on the load (none applied yet)
        self._prev_factor = self._spindle_factor(0.0)
        self._last: dict[str, float] = {}
        self._applied: tuple[object, ...] = ()
        self._reset_observers()
        self._new_tool()
        self._install_effects()
        self._accuracy = RollingAccuracy(
            FORCE_ESTIMATES, self.sample_time, has_truth=self.source.has_truth
        )
        # seed 003's milling machine with eccentricity and its tuner (default scenario)
        k = self._knobs
        self._ecc: LiveEccentricity | None = None
        if self.scenario == "default":
            self._ecc = LiveEccentricity(
                float(k["eccentricity_um"].value),
                float(k["eccentricity_deg"].value),
                tuner=str(k["tuner"].value),
                enabled=bool(k["esc_on"].value),
                force=str(k["ecc_force"].value),
                mass_error_pct=float(k["ecc_mass_error"].value),
            )
        self._apply(0.0)

    def _reset_observers(self) -> None:
        """The harmonic observer from its initial state at the scenario's nominal
        frequencies (retuned by the next :meth:`_apply`)."""
        # seed 002's harmonic observer (DFO) through Q(s) (server.pipeline.stage_harmonics), on the
        # observer with the gated segment identifier's parameters: on the fixed one the
        # workpiece's unmodelled inertia biases the harmonics (measured: 2.8 N m for a
        # true 4.0); on the adaptive (RLS) one its J_L moves at every spindle step and the
        # 100 Hz acceleration times that error reads as a harmonic (measured, 100 s of the
        # default scenario: amplitude error median 9 % / p90 46 %, and after 5 of 6
        # spindle steps not within 5 % in 2 s; on the segment parameters: 0.8 % / 3 %,
        # within 5 % 40-65 ms after every step); retuned, state kept, when the spindle
        # speed changes
        self._dfo = make_dfo(self.run.front.params, tuple(self._force0.frequencies))
        self._dfo_state = dfo_mod.initial_state(self._dfo)

    def _new_tool(self) -> None:
        """A sharp tool: seed 004's wear model on an accelerated clock (default scenario).

        The wear raises the cutting force on the stage (gain = pass force / sharp force);
        the life monitor is fed the force the adaptive observer sees, back in the wear
        model's newtons: ``F_sharp * mean(f_adaptive) / mean(force without wear)``.
        """
        # life_sd=False: the stream shows VB and the remaining life, not its spread,
        # which is ~4/5 of the monitor's time per pass (docs/benchmarks.md)
        self._wear = AcceleratedToolWear(
            wear_minutes_per_second=float(self._knobs["wear_rate"].value), life_sd=False
        )
        self._wear_gain = 1.0
        # the wear's force gain ramps over each pass (mean over the pass = the pass's
        # force): (gain at the pass start, slope per second, pass start time)
        self._gain_ramp = (1.0, 0.0, 0.0)
        self._first_pass = True
        # force of the sharp tool (seed004 (8) at zero wear): the stage's force is scaled by
        # the wear model's force over this one
        self._f_sharp = self._wear.model.force(np.zeros(3), self._wear.feed)
        self._pass_est = self._pass_nom = self._pass_t = 0.0
        self._pass_cut: tuple[float, np.ndarray] | None = None  # (mean force, wear at end)
        self._pass_prev_nom = math.nan  # nominal force of the previous block (none yet)
        self._pass_steady = True  # no change of cutting condition within the pass
        self._vb_true = 0.0
        self._vb_est = math.nan
        self._life_left = math.nan
        self.tools_changed = getattr(self, "tools_changed", -1) + 1
        if self.tools_changed > 0:
            # the CNC knows a tool change: the force's DC steps back to the sharp tool's
            self.run.note_disturbance(self.t)

    def _install_effects(self) -> None:
        fp = self.run.front.params
        self._fx: ObserverEffects | None = None
        if self.effects:
            self._fx = ObserverEffects(
                EffectsParams(self.effects, self.sample_time, fp.q_hz, fp.q_order)
            )
            self._fx_state = self._fx.init_state()

    def set_observer_effects(self, effects: tuple[ObserverEffect, ...]) -> None:
        """Install identified effects (issue 4 section 4) into the live observer; ``()``
        removes them. Their terms are subtracted from the fixed-parameter observer's
        force as :mod:`estimators.residual_two_inertia` does (channel ``f_effects``).

        Raises
        ------
        ParameterError
            An effect without its fitted coefficients.
        """
        effects = tuple(effects)
        if effects:
            fp = self.run.front.params
            EffectsParams(effects, self.sample_time, fp.q_hz, fp.q_order)  # validates
        self.effects = effects
        self._install_effects()

    @property
    def t(self) -> float:
        """Time elapsed: samples taken from the source times the sample time [s]."""
        return float(self.source.t)

    @property
    def finished(self) -> bool:
        """True once the source hands out no more samples (the end of a replayed log)."""
        return bool(self.source.finished)

    # ------------------------------------------------------------------ scenario
    def _spindle_factor(self, t: float) -> float:
        if self.scenario == "seed001-spindle":
            return 0.8 if t >= 11.0 else 1.0
        # the spindle steps belong to the default scenario; the papers' experiments keep a
        # constant force (seed 000 Table III)
        if (
            self.scenario == "default"
            and self._knobs["spindle_changes"].value
            and math.floor(t / SPINDLE_PERIOD) % 2 == 1
        ):
            return 0.8
        return 1.0

    def _apply(self, t: float) -> None:
        """Set the stage's configuration for the block starting at ``t``."""
        k = self._knobs
        sf = self._spindle_factor(t)
        freq = float(k["spindle_rpm"].value) / BASE_RPM * sf
        g0, slope, tp = self._gain_ramp
        self._wear_gain = g0 + slope * max(t - tp, 0.0)
        gain = float(k["feed_scale"].value) * sf * self._wear_gain
        extra = ADDED_WEIGHT_INERTIA if k["weight_on"].value else 0.0
        if self.scenario == "seed000-weight" and t >= 10.0:
            extra = ADDED_WEIGHT_INERTIA
        if extra != self._weight:  # the weight mounted or removed: a known J_L change
            if not math.isnan(self._weight) and self.source.knobs_apply:
                self.run.note_restart(J_L=True)
            self._weight = extra
        if self.scenario == "default":
            # in steps of REMOVAL_STEP: each change of the plant costs a matrix
            # exponential (~1-7 ms here), too much to pay every 50 ms block. A step is
            # applied mid-stroke (>= 1 s from a reversal), where no acceleration shows
            # it: a J_L step inside a reversal is an artefact of the steps (the mass
            # goes continuously) and biased the identified B_L/F_CL when the steps fell
            # on the reversals (removal 2.5 %/s: a step every 2 s, every reversal)
            removed = math.floor(self._removed / REMOVAL_STEP) * REMOVAL_STEP
            hp = self.run.sim.config.trajectory.half_period
            if self._removed == 0.0 or abs(t - round(t / hp) * hp) >= 1.0:
                self._removed_applied = removed
            removed = self._removed_applied
            extra += WORKPIECE_INERTIA * (1.0 - removed)
        if self._ecc is not None:
            self._ecc.configure(
                float(k["eccentricity_um"].value),
                float(k["eccentricity_deg"].value),
                str(k["tuner"].value),
                bool(k["esc_on"].value),
                ECC_BASE_RPM * freq,
                str(k["ecc_force"].value),
                float(k["ecc_mass_error"].value),
            )
        noise = float(k["current_noise"].value)
        effects = tuple(e for e in EFFECT_NAMES if k[f"effect_{e}"].value)
        key = (freq, gain, extra, noise, effects)
        if key == self._applied:
            return
        self._applied = key
        freqs = tuple(f * freq for f in self._force0.frequencies)
        if freqs != tuple(self._dfo.frequencies):
            self._dfo = self._dfo.with_frequencies(freqs)
        # a log or a live feed ignores it (sources.MeasurementSource.knobs_apply)
        self.source.reconfigure(
            force=replace(self._force0, freq_scale=freq, gain=gain),
            extra_inertia=extra,
            current_noise=noise,
            effects=PlantEffects().with_enabled(*effects),
        )

    # ------------------------------------------------------------------ contract
    def channels(self) -> list[Channel]:
        """Every per-sample output of :meth:`step`, with unit and display group."""
        return list(CHANNELS)

    def knobs(self) -> dict[str, Knob]:
        """Live-tweakable parameters with their ranges (the objects themselves)."""
        return dict(self._knobs)

    def set_knob(self, name: str, value: float | bool | str) -> None:
        """Set one knob; validated, nothing changes on error.

        Raises
        ------
        ParameterError
            Unknown name, wrong type, or a value outside the knob's range.
        """
        if name not in self._knobs:
            raise ParameterError("name", f"one of {sorted(self._knobs)}", name)
        k = self._knobs[name]
        if isinstance(k.value, bool):
            if not isinstance(value, bool):
                raise ParameterError(name, "true or false", value)
        elif k.choices is not None:
            if not isinstance(value, str) or value not in k.choices:
                raise ParameterError(name, "one of " + ", ".join(k.choices), value)
        else:
            ok = isinstance(value, int | float) and not isinstance(value, bool)
            v = float(value) if ok else math.nan
            lo, hi = k.min, k.max
            if not (math.isfinite(v) and (lo is None or v >= lo) and (hi is None or v <= hi)):
                raise ParameterError(name, f"a value in [{lo:g}, {hi:g}] {k.unit}".rstrip(), value)
            value = v
        k.value = value

    def step(self, n: int) -> dict[str, np.ndarray]:
        """Advance ``n`` samples; return ``"t"`` and every channel, ``n`` values each.

        Estimates refer to the previous sample (see :mod:`server.pipeline.stage_run`); ``t`` is the
        time they refer to, and the truth columns are aligned to it. A source that has
        fewer samples (the end of a log, a live feed) gives fewer values, or none: then
        nothing changes, not even ``t``. A block the source marks as a discontinuity
        resets every observer first (:meth:`_discontinuity`).
        """
        t0 = float(self.source.t)
        if self.scenario == "default":
            rate = float(self._knobs["removal_rate"].value) / 100.0
            if self._clamp_pending and self._clamp_now(t0):
                self._removed = 0.0  # a fresh blank is clamped
                self._clamp_pending = False
                self.run.note_restart(J_L=True)
            else:
                self._removed = min(self._removed + rate * n * self.sample_time, 1.0)
                ahead = min(rate * CLAMP_LOOKAHEAD, 0.2)  # at most a fifth left uncut
                if not self._clamp_pending and self._removed >= 1.0 - ahead:
                    self._clamp_pending = True
                    self._pending_since = t0
            self._wear_begin(t0)
        factor = self._spindle_factor(t0)
        if factor != self._prev_factor:  # a spindle step: the force's DC changes
            self.run.note_disturbance(t0)
            self._prev_factor = factor
        self._apply(t0)
        block = self.source.step(n)
        self.last_block = block  # the measurements as the source gave them (recording)
        n = block.n
        if n == 0:
            return {"t": np.zeros(0)} | {c.name: np.zeros(0) for c in CHANNELS}
        if block.discontinuity is not None:
            self._discontinuity()
        b = self.run.process(block)
        self._dfo_state, dr = dfo_mod.step(self._dfo, self._dfo_state, b.f_segment)
        f_effects = b.f_fixed
        if self._fx is not None:
            m = b.meas
            # the effects' terms, at t_(k-1) like the observer's (estimators.observer_effects)
            self._fx_state, er = self._fx.step(self._fx_state, b.alpha, m.t, m.q_m, m.q_l, m.tau_m)
            f_effects = b.f_fixed - er.f_corr
        if self.scenario == "default":
            self._wear_pass(n, b.f_adaptive, t0)
        if isinstance(self.source, SimulatorSource):
            f = self.source.config.force
            true_amp = np.asarray(f.amplitudes, dtype=np.float64) * f.gain
        else:
            true_amp = np.full(len(self._force0.amplitudes), math.nan)
        th_a, th_s = b.theta_adaptive, b.theta_switching
        sg = b.segment
        spindle = float(self._knobs["spindle_rpm"].value) * self._spindle_factor(t0)
        out = {
            # b.t_est, except that the very first estimate refers to t = -dt, not 0 twice
            "t": b.meas.t - self.sample_time,
            "f_true": b.f_true,
            "f_fixed": b.f_fixed,
            "f_adaptive": b.f_adaptive,
            "f_switching": b.f_switching,
            "f_segment": b.f_segment,
            "J_L_true": b.truth.J_L,
            "J_L_adaptive": th_a[:, 0],
            "J_L_switching": th_s[:, 0],
            "B_L_true": b.truth.B_L,
            "B_L_adaptive": th_a[:, 1],
            "B_L_switching": th_s[:, 1],
            "F_CL_true": b.truth.F_CL,
            "F_CL_adaptive": th_a[:, 2],
            "F_CL_switching": th_s[:, 2],
            "f_effects": f_effects,
            "f_dfo": dr.d_hat,
            "h1_amp": dr.amplitude[:, 0],
            "h2_amp": dr.amplitude[:, 1],
            "h1_true": np.full(n, true_amp[0]),
            "h2_true": np.full(n, true_amp[1]),
            "vb_true": np.full(n, self._vb_true),
            "vb_est": np.full(n, self._vb_est),
            "vb_limit": np.full(n, VB_LIMIT),
            "life_left": np.full(n, self._life_left),
            **{
                f"{q}_{suffix}": arr[:, j]
                for j, q in enumerate(("J_L", "B_L", "F_CL"))
                for suffix, arr in (
                    ("seg", sg.theta),
                    ("lo", sg.lower),
                    ("hi", sg.upper),
                    ("excited", sg.excited.astype(np.float64)),
                )
            },
            "mode_switching": b.mode_switching.astype(np.float64),
            "excitation": np.full(n, float(b.excitation_index)),
            "omega_l": b.truth.omega_l,
            "spindle_rpm": np.full(n, spindle),
            "q_m": b.meas.q_m,
            "x_l": b.meas.q_l * (SCREW_LEAD / (2 * math.pi)),
        }
        if self._ecc is not None:
            out.update(self._ecc.step(out["t"], self.sample_time))
        else:
            out.update({k: np.full(n, math.nan) for k in ECC_CHANNELS})
        if not self.source.has_truth:
            # no truth but the reference force: the true harmonics and wear are unknown
            for k in ("h1_true", "h2_true", "vb_true", "vb_est", "vb_limit", "life_left"):
                out[k] = np.full(n, math.nan)
        out = {k: np.ascontiguousarray(v, dtype=np.float64) for k, v in out.items()}
        self._score(out, b.f_true, b.f_ideal)
        self._last = {k: float(v[-1]) for k, v in out.items()}
        return out

    def _score(self, out: dict[str, np.ndarray], f_true: np.ndarray, f_ideal: np.ndarray) -> None:
        """The block into the rolling accuracy (:mod:`server.pipeline.accuracy`): against
        the truth, or without one the estimates' agreement with their mean (f_effects
        left out of it while no effect is installed: it is then f_fixed again)."""
        if self.source.has_truth:
            self._accuracy.update(out, f_true, f_ideal)
        else:
            skip = () if self._fx is not None else ("f_effects",)
            self._accuracy.update(out, mean_of=[k for k in FORCE_ESTIMATES if k not in skip])

    def accuracy(self, digits: int | None = None) -> dict[str, object]:
        """Rolling rms of every force estimate over the last 1 s and 10 s
        (:meth:`server.pipeline.accuracy.RollingAccuracy.summary`; ``digits``: rounded,
        JSON-safe)."""
        return self._accuracy.summary(digits)

    def _discontinuity(self) -> None:
        """The source's next block does not continue the last one (a gap, a restart):
        every observer starts again from its initial state, as in a fresh pipeline; the
        wear pass under way is not given to the monitor."""
        self.run.reset_estimators()
        self._dfo_state = dfo_mod.initial_state(self._dfo)
        if self._fx is not None:
            self._fx_state = self._fx.init_state()
        if self._pass_cut is not None:  # a wear pass is under way: it spans the gap
            self._pass_steady = False

    def _wear_begin(self, t0: float) -> None:
        """Start a pass: advance the wear model over it first, so the stage cuts with the
        pass's own wear force (no one-pass lag between the force and the wear clock)."""
        if self._pass_cut is not None or t0 < WEAR_WARMUP_S - 1e-9:
            return
        w = self._wear
        w.rate = float(self._knobs["wear_rate"].value)
        _, f_true, x = w.cut_pass(PASS_S)
        self._pass_cut = (f_true, x)
        # A ramp over the pass whose mean is the pass's force, continuing the previous
        # pass's slope: the wear grows the force smoothly. (It was held in 1 % steps at
        # the pass starts, which fall on the reversals every 4 s: a DC step inside a
        # reversal reads as Coulomb friction, docs/live-identification.md.) A force
        # change costs no matrix exponential (StageSim re-discretises only on a plant
        # change).
        g = f_true / self._f_sharp
        g_prev = self._gain_ramp[0] + 0.5 * self._gain_ramp[1] * PASS_S
        if self._first_pass:
            g_prev = g  # the first pass of a tool
            self._first_pass = False
        slope = (g - g_prev) / PASS_S
        self._gain_ramp = (g - 0.5 * slope * PASS_S, slope, t0)

    def _clamp_now(self, t0: float) -> bool:
        """Clamp the pending fresh blank at this block (start ``t0``)? Just before a
        reversal without a spindle step near it; if the blocks are too long to hit that
        instant, once three half periods have passed."""
        hp = self.run.sim.config.trajectory.half_period
        rev = (math.floor(t0 / hp) + 1) * hp
        if rev - t0 > CLAMP_BEFORE_REVERSAL:
            return t0 - self._pending_since > 3 * hp
        # not at a reversal whose segment a spindle step spoils (every 60 s here): J_L
        # would stay unknown until the next one (the DFO then reads a wrong J_L's
        # acceleration as harmonics, measured: amplitudes 33 % low for 4 s)
        return self._spindle_factor(rev - 1.0) == self._spindle_factor(rev + 1.0)

    def _wear_pass(self, n: int, f_est: np.ndarray, t0: float) -> None:
        """Accumulate the block into the current pass; close the pass every PASS_S."""
        if self._pass_cut is None:  # the wear clock has not started yet
            return
        nominal = self._force0.offset * float(self._knobs["feed_scale"].value)
        nominal *= self._spindle_factor(t0)
        # the mean of the observer's force over a pass is the offset's (the harmonics
        # average out); the nominal mean is what it would be with a sharp tool
        prev, self._pass_prev_nom = self._pass_prev_nom, nominal
        if not math.isnan(prev) and nominal != prev:  # changed in the pass or at its start
            self._pass_steady = False
        self._pass_est += float(np.sum(f_est))
        self._pass_nom += n * nominal
        self._pass_t += n * self.sample_time
        if self._pass_t < PASS_S - 1e-9:
            return
        w = self._wear
        _, x = self._pass_cut
        # a pass in which, or at whose start, the cutting condition changed (spindle step,
        # feed) is not given to the monitor: the observers' transient after the step
        # biases its mean (measured -0.04 mm on VB for the pass after a spindle step)
        if self._pass_nom > 0.0 and self._pass_steady:
            rec = w.observe_pass(self._f_sharp * self._pass_est / self._pass_nom)
            self._vb_est = float(rec.vb[-1])
            self._life_left = float(rec.remaining_life[-1])
        self._vb_true = float(x[0] + x[1])  # flank wear w_f1 + w_f2
        self._pass_est = self._pass_nom = self._pass_t = 0.0
        self._pass_steady = True
        self._pass_cut = None
        if self._vb_true >= VB_LIMIT:  # the tool is changed at the flank-wear limit
            self._new_tool()

    @property
    def latest(self) -> dict[str, float]:
        """Last value of every channel (empty before the first step)."""
        return dict(self._last)

    @property
    def workpiece_removed(self) -> float:
        """Fraction of the current blank removed (default scenario; else 0)."""
        return self._removed

    def snapshot(self) -> dict[str, object]:
        """Latest value of every channel, the truth the source knows and the knob values;
        a source's own status under its name (``"replay"``: path, samples, fed, finished).
        """
        truth = self.source.truth_summary()
        if self.source.has_truth:
            truth["workpiece_removed"] = self._removed
        snap: dict[str, object] = {
            "t": self.t,
            "scenario": self.scenario,
            "latest": dict(self._last),
            "truth": truth,
            "knobs": {k: v.value for k, v in self._knobs.items()},
            "observer_effects": [
                {"name": e.name, "shape": dict(e.shape), "coef": list(e.coef)} for e in self.effects
            ],
            "accuracy": self.accuracy(),
        }
        status = self.source.status()
        if status:
            snap[self.source.name] = status
        return snap
