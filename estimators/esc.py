r"""Extremum seeking cancellation of tool eccentricity (seed003 (8)-(16)).

The cost is the magnitude of the force's spindle-frequency harmonic over the last
revolution (seed003 (8)). The modulation radius :math:`a_m` and phase :math:`\theta_m` are
perturbed sinusoidally once per revolution with phases :math:`\pi/2` apart (seed003 (10), (16)),
the cost is high-pass filtered (seed003 (12)), demodulated by the perturbation
(seed003 (13)-(15)) and
integrated with the step sizes :math:`K_a, K_\theta` (seed003 (9), (16)).

Units follow the paper's Table 1: radius in um, phase in degrees. The estimator sees only
the measured (or estimated) force and the spindle angle; it never sees the eccentricity.

Choices where the paper is ambiguous (also written at the lines concerned):

- **Step-size units.** Table 1 gives :math:`K_a = 45, K_\theta = 50` without units. Here
  the cost is normalised by its value at adaptation start (:math:`j = J/J_0`, so one set
  of gains serves both cases, as the paper states it does), the demodulation multiplies
  by the perturbation itself (seed003 (13), so :math:`\xi \approx \mathrm{diag}(A^2/2)\nabla j`)
  and :math:`K` is an integrator gain in 1/s (seed003 (9)), applied once per revolution as
  :math:`\alpha_n^k = \alpha_n^{k-1} - K\xi_k T_{rev}`. With this reading the units of
  :math:`\alpha` cancel (:math:`K A^2 \partial j/\partial\alpha` has the unit of
  :math:`\alpha` per second), which is why we take it.
- **seed003 (16)** adds the perturbation to :math:`\alpha^{k-1}`; read literally the
  perturbations would accumulate. We add it to the nominal :math:`\alpha_n` (seed003 (10)).
- **Signed radius.** :math:`a_m < 0` is allowed and means the circle at
  :math:`\theta_m + \pi`; the perturbation of seed003 (10) takes :math:`a_m` below zero when
  :math:`a_m < A_a` anyway. :math:`|a_m|` is clamped to ``a_max_um`` and the clamp is
  reported. Results are reported as the equivalent positive radius.
- **Stopping the dither.** The paper notes the dither "can be stopped at the mean value
  after convergence". With ``freeze_revs > 0`` the dither stops when the nominal values
  moved less than ``freeze_tol`` (in units of the perturbation amplitudes) over the last
  ``freeze_revs`` revolutions, and restarts when the cost, averaged over a perturbation
  period, rises above ``resume_ratio`` times its average over the first period after
  freezing (e.g. after a spindle-speed change).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from common.arrays import F64
from estimators.errors import ParameterError, require_in, require_nonnegative, require_positive
from estimators.filters import DiscreteFilter, highpass


def spindle_harmonic(force: ArrayLike, angle: ArrayLike) -> complex:
    r"""The force's harmonic at the spindle frequency over one revolution (seed003 (8)).

    .. math:: F_1 = \frac{2}{L}\sum_{n=0}^{L-1} F(nT_s)\, e^{-j\psi_n}

    ``angle`` is the spindle angle :math:`\psi_n` of each sample (the spindle encoder), which
    equals :math:`\omega_{sp} n T_s` at constant speed and keeps the phase consistent from
    one revolution to the next.

    Choice for a non-integer :math:`L` (1800 rpm at 5 kHz: L = 166.7), where the last
    revolution holds 166 or 167 samples: the sum is taken as a rectangle rule over exactly
    a whole number of revolutions, the last sample weighted by the fraction of its angular
    step that falls inside, and the weighted mean is removed. Without this the large mean
    force and the tooth-passing harmonic leak into the 1x bin by an amount that changes
    from one revolution to the next. For an integer :math:`L` every weight is 1 and the
    mean term sums to zero, so the result is seed003 (8) exactly.

    Raises
    ------
    ParameterError
        If the arrays differ in length or hold fewer than 4 samples.
    """
    f = np.asarray(force, dtype=np.float64)
    a = np.asarray(angle, dtype=np.float64)
    if f.ndim != 1 or f.shape != a.shape or f.size < 4:
        raise ParameterError(
            "force/angle", "two 1-D arrays of the same length >= 4", (f.shape, a.shape)
        )
    # scalars as Python floats (the same IEEE operations as numpy's scalars, faster:
    # this runs once per revolution in the live service)
    n = f.size
    step = (float(a[-1]) - float(a[0])) / (n - 1)
    w_last = 1.0  # every weight is 1 but the last sample's
    if step > 0.0:
        span = n * step
        revs = max(1.0, round(span / (2.0 * math.pi)))
        w_last = min(max(1.0 - (span - 2.0 * math.pi * revs) / step, 0.0), 2.0)
    w_sum = n - 1.0 + w_last
    fm = f - (float(np.sum(f)) + (w_last - 1.0) * float(f[-1])) / w_sum  # weighted mean removed
    c, s = np.cos(a), np.sin(a)
    extra = (w_last - 1.0) * float(fm[-1])
    re = float(fm @ c) + extra * float(c[-1])
    im = float(fm @ s) + extra * float(s[-1])
    return complex(2.0 / w_sum * re, -2.0 / w_sum * im)


def harmonic_cost(force: ArrayLike, angle: ArrayLike) -> float:
    """The cost :math:`J` of seed003 (8): ``abs(spindle_harmonic(force, angle))``."""
    return abs(spindle_harmonic(force, angle))


@dataclass(frozen=True)
class EscParams:
    r"""Extremum seeking controller parameters (defaults: seed 003 Table 1).

    Parameters
    ----------
    k_a, k_theta : float
        Step sizes :math:`K_a, K_\theta` [1/s on the normalised cost], >= 0.
    amp_a_um : float
        Radius perturbation amplitude :math:`A_a` [um], > 0.
    amp_theta_deg : float
        Phase perturbation amplitude :math:`A_\theta` [deg], in (0, 90].
    psi_a, psi_theta : float
        Perturbation phases :math:`\Psi_a, \Psi_\theta` [rad]; their difference must be an
        odd multiple of :math:`\pi/2` so the cross term :math:`D_{2,3}` of seed003 (14) vanishes.
    demod_phase : float
        Phase lag [rad] of the radius channel's demodulation signal behind its
        perturbation (Ariyur & Krstic's compensation of the plant's phase at the dither
        frequency); 0 in the paper and by default.
    demod_phase_theta : float or None
        The same for the phase channel; None (default) uses ``demod_phase``. The two
        channels see different lags: in the simulated cut a radius step shows in the cost
        mostly one revolution late, a phase step mostly at once (see
        docs/reproductions/seed003-eccentricity.md,
        "Why the ESC is slower than the paper").
    period_revs : int
        Perturbation period in revolutions (seed003 (16): 4, i.e. :math:`\omega_p = \pi/2` per
        revolution). Must be >= 3 to be seen by a once-per-revolution cost.
    hpf_cycles_per_rev : float
        High-pass cut-off (seed003 (12)) in cycles per revolution, below ``1/period_revs``.
    a_max_um : float
        Largest modulation radius [um]; the nominal radius is clamped to it.
    freeze_revs : int
        Revolutions of stillness before the dither stops; 0 never stops it.
    freeze_tol : float
        Stillness tolerance, in perturbation amplitudes.
    resume_ratio : float
        After freezing, the dither restarts when the period-mean cost exceeds this times
        the period-mean cost just after freezing.
    """

    k_a: float = 45.0
    k_theta: float = 50.0
    amp_a_um: float = 2.0
    amp_theta_deg: float = 2.0
    psi_a: float = 0.0
    psi_theta: float = math.pi / 2
    period_revs: int = 4
    demod_phase: float = 0.0
    demod_phase_theta: float | None = None
    hpf_cycles_per_rev: float = 0.05
    a_max_um: float = 60.0
    freeze_revs: int = 0
    freeze_tol: float = 0.25
    resume_ratio: float = 3.0

    def __post_init__(self) -> None:
        require_nonnegative("k_a", self.k_a)
        require_nonnegative("k_theta", self.k_theta)
        require_positive("amp_a_um", self.amp_a_um)
        require_in("amp_theta_deg", self.amp_theta_deg, 0.0, 90.0, lo_open=True)
        if int(self.period_revs) != self.period_revs or self.period_revs < 3:
            raise ParameterError("period_revs", "an integer >= 3", self.period_revs)
        # seed003 (14)-(15): D_{2,3} vanishes only if cos(Psi_a - Psi_theta) = 0
        if (
            not (math.isfinite(self.psi_a) and math.isfinite(self.psi_theta))
            or abs(math.cos(self.psi_a - self.psi_theta)) > 1e-9
        ):
            raise ParameterError(
                "psi_theta",
                "a phase differing from psi_a by an odd multiple of pi/2 "
                "(perturbations that decouple, eq. 14)",
                (self.psi_a, self.psi_theta),
            )
        require_in(
            "hpf_cycles_per_rev",
            self.hpf_cycles_per_rev,
            0.0,
            1.0 / self.period_revs,
            lo_open=True,
            hi_open=True,
        )
        require_positive("a_max_um", self.a_max_um)
        if self.amp_a_um >= self.a_max_um:
            raise ParameterError(
                "amp_a_um", f"a value < a_max_um = {self.a_max_um:g}", self.amp_a_um
            )
        if int(self.freeze_revs) != self.freeze_revs or self.freeze_revs < 0:
            raise ParameterError("freeze_revs", "an integer >= 0", self.freeze_revs)
        require_positive("freeze_tol", self.freeze_tol)
        if not math.isfinite(self.demod_phase):
            raise ParameterError("demod_phase", "a finite phase [rad]", self.demod_phase)
        if self.demod_phase_theta is not None and not math.isfinite(self.demod_phase_theta):
            raise ParameterError(
                "demod_phase_theta", "a finite phase [rad] or None", self.demod_phase_theta
            )
        require_in("resume_ratio", self.resume_ratio, 1.0, math.inf, lo_open=True)

    def hpf(self) -> DiscreteFilter:
        """The high-pass of seed003 (12), sampled once per revolution (time unit: 1 rev)."""
        return highpass(self.hpf_cycles_per_rev, 1.0)


@dataclass(frozen=True)
class EscState:
    """Explicit ESC state. Angles in degrees, radius in um."""

    k: int
    a_n_um: float
    theta_n_deg: float
    a_um: float
    theta_deg: float
    j_ref: float
    hpf_state: F64
    frozen: bool
    frozen_cost: float
    history: tuple[tuple[float, float], ...]
    recent_costs: tuple[float, ...] = ()


@dataclass(frozen=True)
class EscRecord:
    """What one revolution's update produced.

    ``cost`` is :math:`J` of the revolution just measured [force unit]; ``a_um``,
    ``theta_deg`` the modulation to apply during the next revolution (nominal plus
    perturbation); ``grad_a``, ``grad_theta`` the demodulated gradient estimate
    :math:`\\xi` (seed003 (15)); ``saturated`` true if the radius was clamped.
    """

    cost: float
    cost_hp: float
    grad_a: float
    grad_theta: float
    a_n_um: float
    theta_n_deg: float
    a_um: float
    theta_deg: float
    saturated: bool
    frozen: bool


class ExtremumSeekingController:
    """Once-per-revolution ESC of seed003 (8)-(16).

    Examples
    --------
    >>> esc = ExtremumSeekingController(EscParams())
    >>> s = esc.initial_state()
    >>> s, rec = esc.step(s, force_one_rev, spindle_angle_one_rev, rev_time_s)  # doctest: +SKIP
    """

    def __init__(self, params: EscParams | None = None) -> None:
        self.params = params if params is not None else EscParams()
        self._hpf = self.params.hpf()
        self._hpf_b: list[float] = self._hpf.b.tolist()
        self._hpf_a: list[float] = self._hpf.a.tolist()

    def initial_state(
        self, a_um: float = 0.0, theta_deg: float = 0.0, cost_ref: float | None = None
    ) -> EscState:
        """State at adaptation start: nominal ``(a_um, theta_deg)`` plus the first
        perturbation.

        ``cost_ref`` is the normaliser :math:`J_0` of the cost: the cost measured without
        modulation (the eccentricity's own level). Give it when the adaptation starts
        from a modulation already near the optimum; otherwise the first revolution's cost
        is used, which near the optimum is small and would make the gains huge.
        """
        p = self.params
        if cost_ref is not None:
            require_positive("cost_ref", cost_ref)
        a = float(a_um)
        if not math.isfinite(a) or abs(a) > p.a_max_um:
            raise ParameterError("a_um", f"a radius with |a| <= a_max_um = {p.a_max_um:g}", a_um)
        th = float(theta_deg)
        if not math.isfinite(th):
            raise ParameterError("theta_deg", "a finite angle", theta_deg)
        pa, pt = self.perturbation(0)
        return EscState(
            k=0,
            a_n_um=a,
            theta_n_deg=th,
            a_um=a + pa,
            theta_deg=th + pt,
            j_ref=0.0 if cost_ref is None else float(cost_ref),
            hpf_state=np.zeros(max(self._hpf.order, 1)),
            frozen=False,
            frozen_cost=0.0,
            history=(),
        )

    def perturbation(self, k: int, lag: float = 0.0) -> tuple[float, float]:
        """seed003 (10)/(16): :math:`(A_a\\sin(\\omega_p k + \\Psi_a), A_\\theta\\sin(\\omega_p k
        + \\Psi_\\theta))` with :math:`\\omega_p = 2\\pi/` ``period_revs`` per revolution."""
        p = self.params
        wp = 2.0 * math.pi / p.period_revs
        return (
            p.amp_a_um * math.sin(wp * k + p.psi_a - lag),
            p.amp_theta_deg * math.sin(wp * k + p.psi_theta - lag),
        )

    def demodulation(self, k: int) -> tuple[float, float]:
        """seed003 (13): the demodulation signals of revolution ``k``, each the perturbation
        delayed by its channel's ``demod_phase`` (0: the perturbation itself)."""
        p = self.params
        th_lag = p.demod_phase if p.demod_phase_theta is None else p.demod_phase_theta
        return self.perturbation(k, lag=p.demod_phase)[0], self.perturbation(k, lag=th_lag)[1]

    def step(
        self,
        state: EscState,
        force: ArrayLike,
        angle: ArrayLike,
        rev_time: float,
        *,
        cost: float | None = None,
    ) -> tuple[EscState, EscRecord]:
        """One revolution: measure the cost of the samples given, update, perturb.

        Parameters
        ----------
        state : EscState
            State whose ``a_um, theta_deg`` were applied during this revolution.
        force, angle : array_like
            Force [N] and spindle angle [rad] of the revolution just finished.
        rev_time : float
            Duration of that revolution [s] (the integrator's time step).
        cost : float, optional
            ``harmonic_cost(force, angle)`` if the caller has computed it already (it is
            not computed again); ``force`` and ``angle`` are then not read.
        """
        p = self.params
        dt = require_positive("rev_time", rev_time)
        if cost is None:
            cost = harmonic_cost(force, angle)
        j_ref = state.j_ref if state.j_ref > 0.0 else max(cost, 1e-12)
        j = cost / j_ref
        # seed003 (12): high-pass the (normalised) cost, once-per-revolution samples: one
        # sample of the filter's transposed DF-II (filters.df2t_step, the same operations
        # in the same order, in Python: a kernel call costs more than one sample)
        z = np.array(state.hpf_state if state.k > 0 else self._hpf.initial_state(j))
        jh = _df2t_one(self._hpf_b, self._hpf_a, z, j)
        # seed003 (13)/(15): demodulate by the perturbation applied during this revolution
        # (delayed per channel by demod_phase[_theta], 0 in the paper and by default)
        da, dt_ = self.demodulation(state.k)
        ga = jh * da
        gt = jh * dt_
        a_n = state.a_n_um
        th_n = state.theta_n_deg
        frozen = state.frozen
        frozen_cost = state.frozen_cost
        recent = state.recent_costs
        if frozen:
            # the reference is the mean cost over the first perturbation period at the
            # held values; the dither restarts when the mean over the latest period
            # exceeds resume_ratio times it (a mean, so one noisy revolution does not)
            recent = (*recent, cost)[-p.period_revs :]
            if len(recent) == p.period_revs:
                mean_recent = sum(recent) / len(recent)
                if frozen_cost <= 0.0:
                    frozen_cost = mean_recent
                elif mean_recent > p.resume_ratio * frozen_cost:
                    frozen = False
                    recent = ()
        if not frozen:
            # seed003 (9)/(16): integrate the gradient estimate with step sizes K (1/s) over
            # one revolution (see module docstring for the unit choice)
            a_n = a_n - p.k_a * ga * dt
            th_n = th_n - p.k_theta * gt * dt
        sat = abs(a_n) > p.a_max_um - p.amp_a_um
        if sat:
            a_n = math.copysign(p.a_max_um - p.amp_a_um, a_n)
        # stillness is judged on adapting revolutions only (reset while frozen)
        hist = () if frozen else (*state.history, (a_n, th_n))[-max(p.freeze_revs, 1) :]
        if (
            not frozen
            and p.freeze_revs > 0
            and len(hist) == p.freeze_revs
            and state.k >= 2 * p.freeze_revs
        ):
            ha, hth = zip(*hist, strict=True)
            da = max(ha) - min(ha)
            dth = max(hth) - min(hth)
            if da < p.freeze_tol * p.amp_a_um and dth < p.freeze_tol * p.amp_theta_deg:
                frozen = True
                frozen_cost = 0.0
                recent = ()
                hist = ()
        k = state.k + 1
        if frozen:
            a, th = a_n, th_n
        else:
            # seed003 (10)/(16): nominal plus the perturbation of the next revolution
            na, nt = self.perturbation(k)
            a, th = a_n + na, th_n + nt
        new = EscState(
            k=k,
            a_n_um=a_n,
            theta_n_deg=th_n,
            a_um=a,
            theta_deg=th,
            j_ref=j_ref,
            hpf_state=z,
            frozen=frozen,
            frozen_cost=frozen_cost,
            history=hist,
            recent_costs=recent,
        )
        rec = EscRecord(
            cost=cost,
            cost_hp=jh,
            grad_a=ga,
            grad_theta=gt,
            a_n_um=a_n,
            theta_n_deg=th_n,
            a_um=a,
            theta_deg=th,
            saturated=sat,
            frozen=frozen,
        )
        return new, rec


def _df2t_one(b: list[float], a: list[float], z: F64, x: float) -> float:
    """One sample of :func:`estimators.filters.df2t_step` in Python; updates ``z``."""
    n = len(a) - 1
    if n == 0:
        return b[0] * x
    # y_k = b_0 x_k + z_0;  z_i <- b_(i+1) x_k - a_(i+1) y_k + z_(i+1)
    y = b[0] * x + float(z[0])
    for i in range(n - 1):
        z[i] = b[i + 1] * x - a[i + 1] * y + float(z[i + 1])
    z[n - 1] = b[n] * x - a[n] * y
    return y


def positive_polar(a_um: float, theta_deg: float) -> tuple[float, float]:
    """The equivalent ``(radius >= 0, phase in [0, 360))`` of a signed radius."""
    if a_um < 0:
        return -a_um, (theta_deg + 180.0) % 360.0
    return a_um, theta_deg % 360.0


__all__ = [
    "EscParams",
    "EscRecord",
    "EscState",
    "ExtremumSeekingController",
    "harmonic_cost",
    "positive_polar",
    "spindle_harmonic",
]
