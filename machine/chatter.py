r"""A tool with its modes cutting on a rigid machine: the chatter benchmark's simulator.

The cut of :mod:`machine.regeneration` with nothing else: the spindle at a set speed, the
tool fed along X at the feed per tooth, the workpiece and the machine rigid but for the
modes given. This is the model of Insperger and Stepan's milling benchmark (and of every
stability lobe), so :mod:`estimators.chatter.lobes` can be checked against it; the machines with
feed drives (:mod:`machine.milling` with a ``structure``) use the same kernels.

Definitions, used by every measurement (docs/chatter.md, "Definitions"):

- *forced vibration*: the vibration of the modes under the chip of the rigid motion
  alone (the forced twin); *non-forced*: the rest, :math:`q - q_{twin}`;
- *amplitude* over a revolution: :math:`\sqrt{2(\sigma_x^2 + \sigma_y^2)}`;
- *onset*: the first time the non-forced amplitude exceeds 10 % of the forced one;
  *developed*: the non-forced amplitude at least the forced one;
- *time-domain stability* (:func:`growth_over`): from rest, the non-forced amplitude
  over revolutions ``settle+46 .. settle+50`` against ``settle-4 .. settle`` (growth
  over 50 revolutions); unstable when it grew by more than 5 % to above 1 % of the
  forced amplitude, when chatter is developed at the end, or when it is saturated: the
  non-forced amplitude still above the onset level (10 % of the forced) while the tool
  leaves the cut (no chip over more than 1 % of the engagement window).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace

import numpy as np
from numba import njit

from common.arrays import F64
from common.cut_geometry import CutGeometry
from common.modes import ModalModel
from machine import regeneration as rg
from machine.errors import ParameterError, require_nonnegative, require_positive

#: rows of the block output of :func:`_cut_block`: the sub-step rows, the truth
#: amplitudes, and the spindle angle
OUT_ROWS = (*rg.SUB_ROWS, "amp_nonforced", "amp_forced", "psi")


@dataclass(frozen=True)
class ChatterCutParams:
    """A cut on a rigid machine with a flexible tool (and workpiece).

    Parameters
    ----------
    modal : ModalModel
        The modes at the cutting point.
    cut : CutGeometry
        Flutes, radial immersion, up/down milling, cutting coefficients.
    axial_depth : float
        Axial depth of cut [m].
    spindle_rpm : float
        Spindle speed [rpm], in [300, 60000].
    feed_per_tooth : float
        Feed per tooth [m] (the nominal chip's scale; a chip thinner than the
        vibration throws the tool out of the cut).
    diameter : float
        Tool diameter [m] (the cutting torque's lever).
    helix_deg, n_layers : float, int
        Helix angle [deg] and axial layers (as :class:`machine.milling.MillingParams`).
    k_te, k_ne : float
        Tangential and normal edge coefficients [N/m] (0 in the benchmark).
    runout : tuple of float
        Radius offset of each flute [m] (empty: none).
    eccentricity, eccentricity_deg : float
        Eccentricity of the tool centre [m], [deg] (seed003 (6)).
    memory_passes : int
        Pitches the surface memory reaches back (0: ``max(4, 2 N)``).
    steps_per_mode_period : int
        Simulation steps per period of the highest mode (>= 16).
    """

    modal: ModalModel
    cut: CutGeometry
    axial_depth: float
    spindle_rpm: float
    feed_per_tooth: float = 0.1e-3
    diameter: float = 10e-3
    helix_deg: float = 0.0
    n_layers: int = 1
    k_te: float = 0.0
    k_ne: float = 0.0
    runout: tuple[float, ...] = ()
    eccentricity: float = 0.0
    eccentricity_deg: float = 0.0
    memory_passes: int = 0
    steps_per_mode_period: int = 64

    def __post_init__(self) -> None:
        if not isinstance(self.modal, ModalModel):
            raise ParameterError("modal", "a ModalModel", type(self.modal).__name__)
        if not isinstance(self.cut, CutGeometry):
            raise ParameterError("cut", "a CutGeometry", type(self.cut).__name__)
        require_nonnegative("axial_depth", self.axial_depth)
        check_rpm(self.spindle_rpm)
        require_positive("feed_per_tooth", self.feed_per_tooth)
        require_positive("diameter", self.diameter)
        if not 0.0 <= self.helix_deg <= 60.0:
            raise ParameterError("helix_deg", "a value in [0, 60]", self.helix_deg)
        if int(self.n_layers) != self.n_layers or not 1 <= self.n_layers <= 200:
            raise ParameterError("n_layers", "an integer in [1, 200]", self.n_layers)
        require_nonnegative("k_te", self.k_te)
        require_nonnegative("k_ne", self.k_ne)
        if self.runout and len(self.runout) != self.cut.n_flutes:
            raise ParameterError("runout", f"{self.cut.n_flutes} radius offsets [m]", self.runout)
        require_nonnegative("eccentricity", self.eccentricity)
        if int(self.memory_passes) != self.memory_passes or self.memory_passes < 0:
            raise ParameterError("memory_passes", "an integer >= 0", self.memory_passes)
        if int(self.steps_per_mode_period) != self.steps_per_mode_period or (
            self.steps_per_mode_period < 16
        ):
            raise ParameterError(
                "steps_per_mode_period", "an integer >= 16", self.steps_per_mode_period
            )

    @property
    def passes(self) -> int:
        n = self.cut.n_flutes
        return int(self.memory_passes) or max(4, 2 * n)

    @property
    def step_time(self) -> float:
        return 1.0 / (self.steps_per_mode_period * self.modal.highest_hz)

    def layer_lags(self, depth: float) -> F64:
        """Lag angle of each axial layer at ``depth`` (seed003 (1))."""
        z = (np.arange(self.n_layers) + 0.5) * depth / self.n_layers
        return np.asarray(2.0 * z * math.tan(math.radians(self.helix_deg)) / self.diameter)


#: slowest spindle speed the surface memory is sized for [rpm]
MIN_RPM = 300.0


def check_rpm(rpm: float) -> float:
    """``rpm`` as a float if the chatter simulation accepts it."""
    v = float(rpm)
    if not math.isfinite(v) or not MIN_RPM <= v <= 60000.0:
        raise ParameterError("spindle_rpm", f"a speed in [{MIN_RPM:g}, 60000] rpm", rpm)
    return v


@njit(cache=True)
def _cut_block(
    n: int,
    dt: float,
    omega: float,
    feed: float,
    ecc: float,
    ecc_ph: float,
    st: F64,
    cut: rg.RegenCut,
    mem: rg.RegenMemory,
    out: F64,
) -> None:  # pragma: no cover
    """``n`` steps of the cut; ``st = [psi, x_feed]`` (updated); ``out`` rows
    :data:`OUT_ROWS`."""
    sub = np.zeros(len(rg.SUB_ROWS))
    for k in range(n):
        psi0 = st[0]
        x0 = st[1]
        psi1 = psi0 + omega * dt
        x1 = x0 + feed * dt
        r0x = x0 + ecc * math.cos(psi0 + ecc_ph)
        r0y = ecc * math.sin(psi0 + ecc_ph)
        r1x = x1 + ecc * math.cos(psi1 + ecc_ph)
        r1y = ecc * math.sin(psi1 + ecc_ph)
        rg.regen_substep(psi0, psi1, r0x, r0y, r1x, r1y, dt, cut, mem, sub)
        for i in range(sub.shape[0]):
            out[i, k] = sub[i]
        out[sub.shape[0], k] = mem.truth[rg.T_ANF]
        out[sub.shape[0] + 1, k] = mem.truth[rg.T_AF]
        out[sub.shape[0] + 2, k] = psi1
        st[0] = psi1
        st[1] = x1


@dataclass
class ChatterRecord:
    """One block of the cut, every row per step (``t`` at the step's end).

    ``fx, fy`` force on the tool [N]; ``qx, qy`` vibration (tool minus workpiece) [m];
    ``nfx, nfy`` its non-forced part [m]; ``amp_nonforced, amp_forced`` the last
    revolution's amplitudes [m]; ``fx_base, fy_base`` force passed to the spindle
    housing [N]; ``torque`` cutting torque on the spindle [N m]; ``chip_max`` largest
    chip [m]; ``engaged`` flute-layer fractions in the cut.
    """

    t: F64
    rows: dict[str, F64] = field(default_factory=dict)

    def __getattr__(self, name: str) -> F64:
        rows = self.__dict__.get("rows", {})
        if name in rows:
            return rows[name]
        raise AttributeError(name)


class ChatterCut:
    """The cut of :class:`ChatterCutParams`, stepped in blocks, with its truth.

    Examples
    --------
    >>> from common.cut_geometry import CutGeometry
    >>> from common.modes import BENCHMARK_1DOF
    >>> p = ChatterCutParams(BENCHMARK_1DOF, CutGeometry(2, 1.0, True, 6e8, 2e8), 0.2e-3, 10000)
    >>> rec = ChatterCut(p).step(1000)
    >>> rec.qx.shape
    (1000,)
    """

    def __init__(self, params: ChatterCutParams) -> None:
        self.params = params
        self.dt = params.step_time
        self._disc = rg.discretise(params.modal, self.dt)
        self._modes = params.modal.packed()
        self.truth = rg.ChatterTruth()
        self.reset()

    def reset(self) -> None:
        """Cut from rest: modes still, the surface the nominal path's."""
        p = self.params
        self._rpm = check_rpm(p.spindle_rpm)
        self._depth = float(p.axial_depth)
        k = len(p.modal.modes)
        self._eta = np.zeros((k, 2))
        self._eta_f = np.zeros((k, 2))
        self._truth = rg.new_truth()
        self._past = np.zeros((max(p.passes, 4), 4))
        self._runout = np.array(p.runout if p.runout else [0.0] * p.cut.n_flutes, dtype=float)
        self._hmeta = np.zeros(2, dtype=np.int64)
        self._hist = np.zeros(
            (
                rg.history_length(p.cut.n_flutes, p.passes, min(self._rpm, 6000.0), self.dt),
                rg.H_COLS,
            )
        )
        rg.fill_history(
            self._hist, self._hmeta, self.dt, self.omega, self.feed_speed(),
            p.eccentricity, math.radians(p.eccentricity_deg),
        )  # fmt: skip
        self._st = np.array([0.0, 0.0])
        self._k = 0
        self._pack()
        self.truth = rg.ChatterTruth()

    def _pack(self) -> None:
        p = self.params
        self._cutp = rg.pack_cut(
            p.cut.n_flutes,
            p.cut.engagement(),
            (p.cut.kt, p.cut.kn, p.k_te, p.k_ne),
            self._depth / p.n_layers,
            0.5 * p.diameter,
            p.passes,
        )
        self._lags = p.layer_lags(self._depth)

    @property
    def omega(self) -> float:
        return 2.0 * math.pi * self._rpm / 60.0

    @property
    def spindle_rpm(self) -> float:
        return self._rpm

    @property
    def axial_depth(self) -> float:
        return self._depth

    @property
    def t(self) -> float:
        return self._k * self.dt

    def feed_speed(self) -> float:
        """Feed rate [m/s] at the current speed (feed per tooth held)."""
        p = self.params
        return p.feed_per_tooth * p.cut.n_flutes * self._rpm / 60.0

    def samples_per_revolution(self) -> float:
        return 60.0 / (self._rpm * self.dt)

    def set_spindle_rpm(self, rpm: float) -> None:
        """Change the speed now (the feed follows; the memory grows if it must)."""
        self._rpm = check_rpm(rpm)
        p = self.params
        need = rg.history_length(p.cut.n_flutes, p.passes, self._rpm, self.dt)
        if need > self._hist.shape[0]:
            self._hist, self._hmeta = rg.grow_history(self._hist, self._hmeta, need)

    def set_axial_depth(self, depth: float) -> None:
        """Change the axial depth now (a step in the workpiece)."""
        self._depth = require_nonnegative("axial_depth", depth)
        self._pack()

    def step(self, n: int) -> ChatterRecord:
        """Advance ``n`` steps; the record holds every step, the truth is updated."""
        if int(n) != n or n < 0:
            raise ParameterError("n", "an integer >= 0", n)
        n = int(n)
        p = self.params
        out = np.empty((len(OUT_ROWS), n))
        cut = rg.RegenCut(self._cutp, self._lags, self._runout, self._modes, self._disc)
        mem = rg.RegenMemory(
            self._eta, self._eta_f, self._hist, self._hmeta, self._truth, self._past
        )
        _cut_block(
            n, self.dt, self.omega, self.feed_speed(), p.eccentricity,
            math.radians(p.eccentricity_deg), self._st, cut, mem, out,
        )  # fmt: skip
        t = np.asarray((self._k + 1 + np.arange(n)) * self.dt, dtype=np.float64)
        self._k += n
        rec = ChatterRecord(t=t, rows={name: out[i] for i, name in enumerate(OUT_ROWS)})
        self.truth.update(t, rec.amp_nonforced, rec.amp_forced, rec.nfx, rec.nfy)
        return rec

    def run_revolutions(self, revs: float) -> ChatterRecord:
        """Advance ``revs`` revolutions at the current speed (one record)."""
        return self.step(round(revs * self.samples_per_revolution()))


#: growth over 50 revolutions above which a cut is unstable (the stationary residue of a
#: chip clipped by the forced vibration, or of regenerated runout, grows by 1.000-1.002)
GROWTH_LIMIT = 1.05
#: non-forced amplitude, as a fraction of the forced one, below which growth is ignored
NEGLIGIBLE = 0.01
#: the onset level: non-forced amplitude over forced (docs/chatter.md, "Definitions")
ONSET = 0.1
#: share of the engagement window without a chip above which the tool leaves the cut
OUT_OF_CUT = 0.01


@dataclass(frozen=True)
class Growth:
    """The time-domain stability verdict of one cut."""

    growth: float  #: non-forced amplitude, last 5 revolutions / 5 revolutions 50 earlier
    developed: bool  #: non-forced >= forced over the last 5 revolutions
    amp_forced: float  #: [m], last 5 revolutions
    amp_nonforced: float  #: [m], last 5 revolutions
    frequency_hz: float
    out_of_cut: float = 0.0  #: share of the engagement window without a chip, last 5 revs

    @property
    def grew(self) -> bool:
        """Grown by more than :data:`GROWTH_LIMIT` to above :data:`NEGLIGIBLE` of forced."""
        return self.growth > GROWTH_LIMIT and self.amp_nonforced > NEGLIGIBLE * self.amp_forced

    @property
    def saturated(self) -> bool:
        """Saturated chatter: the non-forced vibration still above the onset level (10 %
        of the forced) while the tool leaves the cut (no chip over more than
        :data:`OUT_OF_CUT` of the engagement window). A stable cut near the boundary can
        still be above the onset level after 60 revolutions, decaying slowly, but it
        does not throw the tool out of the cut."""
        return self.amp_nonforced > ONSET * self.amp_forced and self.out_of_cut > OUT_OF_CUT

    @property
    def stable(self) -> bool:
        """Stable unless it grew, is developed, or is saturated (docs/chatter.md,
        "Definitions")."""
        return not (self.grew or self.developed or self.saturated)

    @property
    def stable_as_first_defined(self) -> bool:
        """The criterion as first written: stable unless it grew (by any amount) or is
        developed; kept to report what the amendments changed."""
        return not (self.growth > 1.0 or self.developed)


def growth_over(params: ChatterCutParams, revolutions: int = 50, settle: int = 10) -> Growth:
    """Simulate from rest for ``settle + revolutions`` revolutions; the growth of the
    non-forced amplitude over the last ``revolutions`` (windows of 5 revolutions)."""
    if revolutions < 5 or settle < 5:
        raise ParameterError("revolutions/settle", "both >= 5", (revolutions, settle))
    cut = ChatterCut(params)
    rec = cut.run_revolutions(settle + revolutions + 1)
    a, f = per_revolution(rec)
    a = a[: settle + revolutions]
    f = f[: settle + revolutions]
    early = float(np.mean(a[settle - 5 : settle]))
    late = float(np.mean(a[-5:]))
    forced = float(np.mean(f[-5:]))
    growth = late / early if early > 0 else (math.inf if late > 0 else 0.0)
    last = rec.t > rec.t[-1] - 5.0 * 60.0 / params.spindle_rpm
    window = float(np.sum(rec.engaged[last]))
    out = 1.0 - float(np.sum(rec.in_cut[last])) / window if window > 0 else 0.0
    return Growth(growth, late >= forced > 0.0, forced, late, cut.truth.frequency(), out)


def per_revolution(rec: ChatterRecord) -> tuple[F64, F64]:
    """Non-forced and forced amplitude of each whole revolution in ``rec`` (the truth rows
    hold a revolution's amplitudes from the first sample of the next one)."""
    rev = np.floor(rec.psi / (2.0 * math.pi)).astype(np.int64)
    first = np.flatnonzero(np.diff(rev) > 0) + 1  # first sample of each new revolution
    return rec.amp_nonforced[first], rec.amp_forced[first]


def with_depth(params: ChatterCutParams, depth: float) -> ChatterCutParams:
    """The same cut at another depth."""
    return replace(params, axial_depth=depth)


def with_speed(params: ChatterCutParams, rpm: float) -> ChatterCutParams:
    """The same cut at another speed."""
    return replace(params, spindle_rpm=rpm)


__all__ = [
    "GROWTH_LIMIT",
    "MIN_RPM",
    "NEGLIGIBLE",
    "ONSET",
    "OUT_OF_CUT",
    "OUT_ROWS",
    "ChatterCut",
    "ChatterCutParams",
    "ChatterRecord",
    "Growth",
    "check_rpm",
    "growth_over",
    "per_revolution",
    "with_depth",
    "with_speed",
]
