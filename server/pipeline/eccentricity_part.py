"""Eccentricity and its cancellation, run beside the live stage (seed 003 in the loop).

:class:`EccentricityPart` is the live part (:mod:`server.pipeline.part`): its channels and
charts are declared here; it simulates seed 003's milling machine beside the stage, so it
runs with the simulator only. :class:`LiveEccentricity` wraps
:class:`harness.eccentricity_loop.EccentricityLoop` (milling machine on its X/Y
feed drives at 5 kHz, extremum seeking controller or fast tuner) for the live pipeline:
each block of the stage (2.5 kHz) advances it by the same simulated time (the fractional
remainder carried over), and its per-revolution values are picked on the stage's sample
grid so they stream with every other channel.

Choices
-------
- The milling spindle follows the live spindle: ``1200 rpm * spindle_rpm / 3000`` (seed
  003's case 1 at the knob's default), including the default scenario's 80 % steps, so the
  tuner has speed changes to track.
- By default the tuner sees the dynamometer's X force (as in seed 003's experiment): the
  observer force source costs about 1.7x the CPU (``docs/live-service.md``,
  eccentricity). The ``ecc_force`` knob gives it the seed-000 observers' force instead
  (``observer``: fixed mass; ``adaptive``: mass identified at spindle order N_f + 1/8,
  :class:`harness.eccentricity_loop.AdaptiveObserverForceSource`), with the
  observer's nominal mass off by ``ecc_mass_error`` percent; ``f1x`` (true 1x amplitude)
  then differs from ``cost`` (the estimate's). With the fast tuner the adaptive
  observer identifies for two windows and then switches its circle off (the circle
  disturbs the fast tuner's one-revolution phasors; docs/reproductions/seed003-eccentricity.md).
  Changing either knob rebuilds the observers and restarts the tuner.
- Switching the tuner or ESC on/off keeps the machine running and restarts the tuner
  from zero modulation at the current time (a new adaptation, as at 1 s in Fig. 3).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, replace

import numpy as np

from common.arrays import F64
from common.errors import ParameterError
from estimators.esc import EscParams
from harness.eccentricity_loop import (
    AdaptiveObserverForceSource,
    EccentricityLoop,
    ForceSource,
    LoopState,
    ObserverForceSource,
)
from machine.milling import MillingParams
from server.pipeline.machine_view import MachineView
from server.pipeline.part import (
    Block,
    Channel,
    Chart,
    LivePart,
    Outputs,
    Setup,
    Verdict,
    needs_simulator,
)

#: revolutions of the tuner's log kept in the live service
LOG_KEEP = 64

#: milling spindle speed at the live knob's base speed (seed 003 Table 1, case 1)
ECC_BASE_RPM = 1200.0
#: the ESC of seed 003 Table 1 with the dither stopped after convergence
#: (docs/reproductions/seed003-eccentricity.md: "ESC details")
ESC_LIVE = EscParams(k_a=45.0, k_theta=50.0, amp_a_um=2.0, amp_theta_deg=2.0, freeze_revs=40)
TUNERS = ("esc", "fast")
#: delay of the tuner's start after its force source changed [s]
OBSERVER_SETTLE_S = 1.0
#: where the tuner's force comes from
FORCE_SOURCES = ("dynamometer", "observer", "adaptive")

#: channel name -> (unit, label); all on the slow display grid (group "eccentricity")
ECC_CHANNELS: dict[str, tuple[str, str]] = {
    "ecc_a_m": ("um", "modulation radius a_m applied by the tuner"),
    "ecc_theta_m": ("deg", "modulation phase theta_m applied by the tuner"),
    "ecc_a_cancel": ("um", "true cancelling radius"),
    "ecc_theta_cancel": ("deg", "true cancelling phase"),
    "ecc_cost": ("N", "tuner's cost: seed003 (8) 1x amplitude of F_x, last revolution"),
    "ecc_f1x": ("N", "1x amplitude of the true F_x, last revolution"),
    "ecc_true_um": ("um", "true tool eccentricity radius"),
    "ecc_true_deg": ("deg", "true tool eccentricity angle"),
    "ecc_fast_on": ("", "fast tuner running (1) or not (0)"),
    "ecc_esc_on": ("", "ESC running (1) or not (0)"),
    "ecc_mass_err": ("%", "X mass of the tuner's observer (fixed or identified) vs true"),
    "ecc_identifying": ("", "adaptive observer's identification circle on (1) or not (0)"),
}


#: rows of the channels held over a block, in the order :meth:`LiveEccentricity.step` gives
_HELD_ROWS = tuple(
    list(ECC_CHANNELS).index(k)
    for k in (
        "ecc_a_cancel",
        "ecc_theta_cancel",
        "ecc_f1x",
        "ecc_true_um",
        "ecc_true_deg",
        "ecc_fast_on",
        "ecc_esc_on",
        "ecc_mass_err",
        "ecc_identifying",
    )
)


class LiveEccentricity:
    """The eccentricity loop advanced by the stage's blocks.

    Parameters
    ----------
    eccentricity_um, eccentricity_deg : float
        Tool eccentricity (radius [um], angle [deg]).
    tuner : {"esc", "fast"}
        Which tuner runs when ``enabled``.
    enabled : bool
        Cancellation on (else the tuner is off and no modulation is applied).
    adapt_start_s : float
        Simulated time at which the first adaptation starts.
    force : {"dynamometer", "observer", "adaptive"}
        The tuner's force: true, fixed observer, adaptive observer.
    mass_error_pct : float
        Error of the observers' nominal mass [%].
    """

    def __init__(
        self,
        eccentricity_um: float = 20.0,
        eccentricity_deg: float = 40.0,
        *,
        tuner: str = "esc",
        enabled: bool = True,
        adapt_start_s: float = 1.0,
        force: str = "dynamometer",
        mass_error_pct: float = 0.0,
    ) -> None:
        mp = MillingParams(eccentricity=eccentricity_um * 1e-6, eccentricity_deg=eccentricity_deg)
        self.loop = EccentricityLoop(
            mp, tuner=tuner if enabled else "off", esc=ESC_LIVE, adapt_start_s=adapt_start_s
        )
        self.sample_time = self.loop.machine.sample_time
        self._carry = 0.0
        self._last: dict[str, float] = {}
        self._key: tuple[float, float, str, float, str, float] = (
            eccentricity_um,
            eccentricity_deg,
            self.loop.tuner,
            ECC_BASE_RPM,
            "dynamometer",
            0.0,
        )
        self._cancel = self.loop.machine.cancelling_modulation()
        self._set_force(force, mass_error_pct)

    def _set_force(self, force: str, mass_error_pct: float) -> None:
        """Give the tuner the force of ``force`` (observers built from now on)."""
        lp = self.loop
        m = lp.machine
        m.set_excitation(0.0, 1.5)
        src: ForceSource | None = None
        me = mass_error_pct / 100.0
        if force == "observer":
            src = ObserverForceSource(m.drives.params, mass_error=me)
        elif force == "adaptive":
            # identify, then hold, when the fast tuner runs (module docstring)
            stop = 2 if lp.tuner == "fast" else None
            ad = AdaptiveObserverForceSource(m, mass_error=me, stop_after=stop)
            ad.attach(m)
            src = ad
        lp.force_source = src
        self._key = (*self._key[:4], force, float(mass_error_pct))

    def _mass_error(self) -> tuple[float, float]:
        """(X mass error [%], circle on) of the tuner's observer; NaN without one."""
        src = self.loop.force_source
        if isinstance(src, AdaptiveObserverForceSource):
            return 100.0 * src.mass_errors()[0], 1.0 if src.identifying else 0.0
        if isinstance(src, ObserverForceSource):
            return self._key[5], 0.0
        return math.nan, 0.0

    def configure(
        self,
        eccentricity_um: float,
        eccentricity_deg: float,
        tuner: str,
        enabled: bool,
        rpm: float,
        force: str = "dynamometer",
        mass_error_pct: float = 0.0,
    ) -> None:
        """Apply the knobs (cheap when nothing changed)."""
        mode = tuner if enabled else "off"
        key = (
            float(eccentricity_um),
            float(eccentricity_deg),
            mode,
            float(rpm),
            str(force),
            float(mass_error_pct),
        )
        if key == self._key:
            return
        lp = self.loop
        m = lp.machine
        if key[:2] != self._key[:2]:
            # the eccentricity is read by the machine's kernel every block
            m.milling = replace(m.milling, eccentricity=key[0] * 1e-6, eccentricity_deg=key[1])
        if key[3] != self._key[3]:
            lp.set_spindle_rpm(key[3])
        new_force = key[4:] != self._key[4:] or (mode != self._key[2] and key[4] != "dynamometer")
        if mode != self._key[2] or new_force:
            # a new adaptation from zero modulation, starting now
            lp.tuner = mode
            lp.esc_state = lp.esc.initial_state()
            lp.fast_state = lp.fast.initial_state()
            lp.a_um = lp.theta_deg = lp.b_um = lp.phi_deg = 0.0
            lp.a_n_um = lp.theta_n_deg = 0.0
            lp._started = False
            # new observers: their first samples start from rest (a spike in the
            # estimated force) and the adaptive one needs ~2 windows (0.8 s at 1200 rpm)
            # for the mass, so the tuner starts a second later (its cost reference is
            # the revolution before it starts)
            lp.adapt_start_s = m.t + (OBSERVER_SETTLE_S if new_force else 0.0)
        self._key = (*key[:4], *self._key[4:])
        if new_force:
            self._set_force(key[4], key[5])
        self._cancel = m.cancelling_modulation()

    def step(self, t: F64, dt: float) -> dict[str, F64]:
        """Advance by ``t.size * dt`` of simulated time; channels picked at the times ``t``.

        Each output value is the loop's value at the latest of its samples not after the
        stage sample (the tuner's values change once per revolution).
        """
        n = t.size
        want = n * dt / self.sample_time + self._carry
        m = int(math.floor(want + 1e-9))
        self._carry = want - m
        if m <= 0:
            return self._hold(n)
        out = self.loop.step(m)
        te = out["t"]
        idx = np.clip(np.searchsorted(te, t + 1e-12, side="right") - 1, 0, m - 1)
        log = self.loop.log
        f1x = log.cost_true[-1] if log.cost_true else math.nan
        # the per-revolution log is for offline runs; live, keep only its tail (it grew
        # the service by 0.28 MB/min over a 30-minute soak: 20 revolutions/s x 10 lists)
        if len(log.t_end) > LOG_KEEP:
            for entries in log.__dict__.values():
                del entries[:-LOG_KEEP]
        lp = self.loop
        mass_err, ident = self._mass_error()
        a_c, th_c = self._cancel
        a = out["a_m_um"][idx]
        # one array for every channel: the picked rows, then the values held over the block
        rows = np.empty((len(ECC_CHANNELS), n))
        rows[0] = np.abs(a)
        # a negative radius is the circle at theta + 180 deg (estimators.esc)
        rows[1] = np.mod(out["theta_m_deg"][idx] + np.where(a < 0.0, 180.0, 0.0), 360.0)
        rows[4] = out["cost"][idx]
        held = (
            a_c * 1e6,
            math.degrees(th_c),
            f1x,
            self._key[0],
            self._key[1],
            1.0 if lp.tuner == "fast" and lp._started else 0.0,
            1.0 if lp.tuner == "esc" and lp._started else 0.0,
            mass_err,
            ident,
        )
        for row, v in zip(_HELD_ROWS, held, strict=True):
            rows[row] = v
        res = dict(zip(ECC_CHANNELS, rows, strict=True))
        self._last = dict(zip(ECC_CHANNELS, rows[:, -1].tolist(), strict=True))
        return res

    def _hold(self, n: int) -> dict[str, F64]:
        return {k: np.full(n, self._last.get(k, math.nan)) for k in ECC_CHANNELS}

    def state(self) -> dict[str, float | bool | str]:
        """The loop's latest values (see :meth:`EccentricityLoop.state`)."""
        return self.loop.state()


#: the charts of the tuner: radius, phase, cost (the research page)
ECC_RADIUS = Chart(
    "ecc_radius", "Eccentricity: ESC radius (tuner vs cancelling)", order=60, window_s=60.0
)
ECC_PHASE = Chart("ecc_phase", "Eccentricity: ESC phase", order=61, window_s=60.0)
ECC_COST = Chart(
    "ecc_cost", "Eccentricity: cost, 1x force, observer mass error", order=62, window_s=60.0
)
#: how each channel is drawn: chart, truth, colour, second axis, legend
_DRAWN: dict[str, tuple[Chart | None, bool, str, str, str]] = {
    "ecc_a_cancel": (ECC_RADIUS, True, "#1d232b", "", "cancelling a_m (true) [um]"),
    "ecc_a_m": (ECC_RADIUS, False, "#0072b2", "", "tuner a_m [um]"),
    "ecc_fast_on": (ECC_RADIUS, False, "#7b3294", "on", "fast tuner on"),
    "ecc_esc_on": (ECC_RADIUS, False, "#009e73", "on", "ESC on"),
    "ecc_theta_cancel": (ECC_PHASE, True, "#1d232b", "", "cancelling theta_m (true) [deg]"),
    "ecc_theta_m": (ECC_PHASE, False, "#0072b2", "", "tuner theta_m [deg]"),
    "ecc_cost": (ECC_COST, False, "#0072b2", "", "cost, eq. (8) [N]"),
    "ecc_f1x": (ECC_COST, True, "#1d232b", "", "1x force amplitude, true [N]"),
    "ecc_mass_err": (ECC_COST, False, "#cc3311", "pct", "observer X mass error [%]"),
    "ecc_true_um": (None, True, "", "", ""),
    "ecc_true_deg": (None, True, "", "", ""),
    "ecc_identifying": (None, False, "", "", ""),
}


def _channels() -> tuple[Channel, ...]:
    """:data:`ECC_CHANNELS` declared (each on its chart, in the order listed there)."""
    out: list[Channel] = []
    for chart in (ECC_RADIUS, ECC_PHASE, ECC_COST, None):
        mine = [k for k, d in _DRAWN.items() if d[0] is chart]
        chans = [
            Channel(k, ECC_CHANNELS[k][0], ECC_CHANNELS[k][1], "eccentricity", truth=_DRAWN[k][1],
                    color=_DRAWN[k][2], axis=_DRAWN[k][3],
                legend=_DRAWN[k][4])
            for k in mine
        ]  # fmt: skip
        out += chart.series(*chans) if chart is not None else chans
    return tuple(out)


@dataclass
class EccentricityState:
    """The eccentricity part's state (checkpointed): the knobs it applied (radius, angle,
    tuner mode, milling spindle speed, force source, mass error), the fractional sample
    carried to the next block, the latest values and the true cancelling modulation, and
    the loop's own state (the simulated machine, the force observers, the tuner)."""

    key: tuple[float, float, str, float, str, float]
    carry: float
    last: dict[str, float]
    cancel: tuple[float, float]
    loop: LoopState


class EccentricityPart(LivePart):
    """Seed 003's eccentric milling tool and its tuner, beside the stage (module docstring).

    Parameters
    ----------
    live
        The loop, advanced by the stage's blocks.
    """

    name = "eccentricity"
    charts = (ECC_RADIUS, ECC_PHASE, ECC_COST)
    channels = _channels()

    def __init__(self, live: LiveEccentricity) -> None:
        self.live = live

    @property
    def simulated_s(self) -> float:  # type: ignore[override]
        """Seconds in seed 003's simulated milling machine (the rest: tuner, observers)."""
        return self.live.loop.sim_s

    @classmethod
    def from_knobs(cls, k: Mapping[str, float | bool | str]) -> EccentricityPart:
        """The part as the knobs set it (radius, angle, tuner, on/off, force, mass error)."""
        return cls(
            LiveEccentricity(
                float(k["eccentricity_um"]),
                float(k["eccentricity_deg"]),
                tuner=str(k["tuner"]),
                enabled=bool(k["esc_on"]),
                force=str(k["ecc_force"]),
                mass_error_pct=float(k["ecc_mass_error"]),
            )
        )

    def requires(self, machine: MachineView) -> Verdict:
        return needs_simulator(machine, "seed 003's milling machine with its eccentric tool")

    def configure(self, setup: Setup) -> None:
        """The knobs, and the milling spindle following the machine's spindle."""
        from server.pipeline.knobs import BASE_RPM  # (knobs lists this module's choices)

        k = setup.knobs
        self.live.configure(
            float(k["eccentricity_um"]),
            float(k["eccentricity_deg"]),
            str(k["tuner"]),
            bool(k["esc_on"]),
            ECC_BASE_RPM * (setup.machine.spindle_rpm / BASE_RPM),
            str(k["ecc_force"]),
            float(k["ecc_mass_error"]),
        )

    def step(self, block: Block) -> Outputs:
        return self.live.step(block.t, block.sample_time), []

    def state(self) -> EccentricityState:
        lv = self.live
        return EccentricityState(
            lv._key, lv._carry, dict(lv._last), lv._cancel, lv.loop.loop_state()
        )

    def restore(self, state: object) -> None:
        if not isinstance(state, EccentricityState):
            raise ParameterError(
                "state.parts.eccentricity", "an EccentricityState", type(state).__name__
            )
        lv = self.live
        lv._key, lv._carry, lv._last = state.key, state.carry, dict(state.last)
        lv._cancel = state.cancel
        lv.loop.restore_loop(state.loop)


__all__ = [
    "ECC_CHANNELS",
    "FORCE_SOURCES",
    "TUNERS",
    "EccentricityPart",
    "EccentricityState",
    "LiveEccentricity",
]
