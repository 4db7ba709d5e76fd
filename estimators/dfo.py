r"""Harmonic disturbance force observer (DFO) of seed 002 Section 4.3, seed002 (5)-(9).

A disturbance made of sinusoids of known frequencies, seed002 (5)-(7),

.. math::

    d_i(t) = A_i \sin(\omega_i t + \theta_i), \quad \dot d_i = A_i\omega_i\cos(\cdot),
    \quad \ddot d_i = -\omega_i^2 d_i ,

is the state of an undamped oscillator. Each harmonic contributes the states
:math:`s_i = A_i\sin(\omega_i t + \theta_i)` and :math:`c_i = \dot d_i/\omega_i`, so
amplitude and phase are read off directly. They drive a known linear *channel*
:math:`P(s)` together with a known (possibly delayed) input :math:`u`,

.. math::

    y = P(s)\,\Bigl[u(t - T_d) + \sum_i s_i\Bigr],

and a state observer, seed002 (8)-(9), :math:`\dot{\hat x} = F\hat x + G u + L(y - H\hat x)`,
estimates plant and harmonic states together; the gain ``L`` comes from pole placement.

Two channels are used in cutwatch: the x-axis of seed 002 (``P = A/(s^2 + B s + C)``, the
input is the delayed command, ``y`` the position), and a cutting-force observer's output
(``P = Q(s)``, its low-pass; no input): there the DFO undoes Q's attenuation and lag at the
tooth-passing harmonics.

Discretisation (our choice; the paper's observer is continuous): the augmented model is
discretised exactly (ZOH command, fractional delay split as in the plant) and the observer
runs in current-estimator form, its error poles placed at ``exp(p T)`` of the continuous
design poles ``p``; this keeps the estimate free of the bias that a continuous observer fed
with a sampled-and-held ``y`` would carry.
"""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass, field, replace
from typing import NamedTuple

import numpy as np
from numba import njit
from numpy.typing import ArrayLike, NDArray

from common.arrays import F64
from common.linalg import zoh
from estimators.errors import ParameterError, require_nonnegative, require_positive


def _balance(m: F64) -> F64:
    """Diagonal ``s`` with ``diag(s)^-1 m diag(s)`` of balanced row/column norms."""
    a = m.copy()
    s = np.ones(a.shape[0])
    for _ in range(30):
        done = True
        for i in range(a.shape[0]):
            c = float(np.linalg.norm(np.delete(a[:, i], i)))
            r = float(np.linalg.norm(np.delete(a[i, :], i)))
            if c > 0 and r > 0:
                f = math.sqrt(r / c)
                if abs(math.log(f)) > 0.05:
                    done = False
                a[:, i] *= f
                a[i, :] /= f
                s[i] *= f
        if done:
            break
    return s


def place_observer(f: F64, h: F64, poles: ArrayLike) -> F64:
    """Gain ``L`` with ``eig(f - L h) = poles`` (single output, distinct poles).

    Solved on the dual single-input system by the eigenvector method
    (``w_i = (f^T - p_i I)^-1 h^T``, ``L^T W = 1``) after diagonal balancing; the result
    is verified and :class:`ParameterError` raised if the placement is not accurate.
    """
    p = np.asarray(poles, dtype=np.complex128)
    n = f.shape[0]
    if p.shape != (n,):
        raise ParameterError("poles", f"{n} poles", p.shape)
    at = f.T.copy()
    s = _balance(at)
    a_s = at * s[None, :] / s[:, None]
    b_s = h / s
    w = np.empty((n, n), dtype=np.complex128)
    for i in range(n):
        w[:, i] = np.linalg.solve(a_s - p[i] * np.eye(n), b_s)
    k_s = np.linalg.solve(w.T, np.ones(n, dtype=np.complex128))
    gain = np.real(k_s) / s
    got = np.sort_complex(np.linalg.eigvals(f - np.outer(gain, h)))
    want = np.sort_complex(p)
    scale = max(1.0, float(np.max(np.abs(p))))
    if np.max(np.abs(got - want)) > 1e-5 * scale:
        raise ParameterError(
            "poles",
            "poles the observer can reach accurately (distinct, "
            "well separated, not at the model's own eigenvalues)",
            list(p),
        )
    return np.asarray(gain)


@dataclass(frozen=True, eq=False)
class DfoParams:
    """Harmonic observer for known frequencies.

    Parameters
    ----------
    frequencies : tuple of float
        Harmonic frequencies [Hz], distinct, in (0, Nyquist).
    sample_time : float
        [s].
    channel_num, channel_den : tuple of float
        Continuous ``P(s)`` from ``u + d`` to ``y`` (highest power first), strictly proper
        or a static gain.
    input_delay : float
        Delay [s] of the known input ``u`` (not of the disturbance), >= 0.
    uses_input : bool
        Whether a known input drives the channel (then :func:`apply` must follow each
        :func:`step`).
    harmonic_decay : float
        Real part magnitude [1/s] of the observer poles placed at ``-decay +- j omega_i``
        (time constant of the amplitude/phase estimates).
    channel_bandwidth_hz : float
        The channel states' observer poles sit at ``-2 pi f_b (1 + 0.25 i)``.
    lead : float
        The compensation is the harmonic estimate predicted ``lead`` seconds ahead
        (0 = the paper's DFO; the input delay would make it exact for sinusoids).
    include_offset : bool
        Also estimate a constant part of the disturbance (one more state, observer pole at
        ``-decay``); it joins ``d_hat`` and the compensation. Not in the paper (its
        disturbance is pure harmonics); a milling force has a mean.
    """

    frequencies: tuple[float, ...]
    sample_time: float
    channel_num: tuple[float, ...] = (1.0,)
    channel_den: tuple[float, ...] = (1.0,)
    input_delay: float = 0.0
    uses_input: bool = False
    harmonic_decay: float = 2 * math.pi * 5.0
    channel_bandwidth_hz: float = 100.0
    lead: float = 0.0
    include_offset: bool = False
    phi: F64 = field(init=False, repr=False)
    gamma_a: F64 = field(init=False, repr=False)
    gamma_b: F64 = field(init=False, repr=False)
    h: F64 = field(init=False, repr=False)
    gain: F64 = field(init=False, repr=False)
    lead_cos: F64 = field(init=False, repr=False)
    lead_sin: F64 = field(init=False, repr=False)
    channel_order: int = field(init=False)
    delay_samples: int = field(init=False)

    def __post_init__(self) -> None:
        ts = require_positive("sample_time", self.sample_time)
        nyq = 0.5 / ts
        freqs = tuple(float(x) for x in self.frequencies)
        if len(freqs) < 1:
            raise ParameterError("frequencies", "at least one frequency", freqs)
        for fr in freqs:
            if not math.isfinite(fr) or fr <= 0 or fr >= nyq:
                raise ParameterError("frequencies", f"frequencies in (0, {nyq:g}) Hz (Nyquist)", fr)
        srt = sorted(freqs)
        for a, b in itertools.pairwise(srt):
            if b - a <= 1e-9 * b:
                raise ParameterError("frequencies", "distinct frequencies", freqs)
        object.__setattr__(self, "frequencies", freqs)
        require_nonnegative("input_delay", self.input_delay)
        require_positive("harmonic_decay", self.harmonic_decay)
        require_positive("channel_bandwidth_hz", self.channel_bandwidth_hz)
        require_nonnegative("lead", self.lead)
        num = np.trim_zeros(np.asarray(self.channel_num, dtype=np.float64), "f")
        den = np.trim_zeros(np.asarray(self.channel_den, dtype=np.float64), "f")
        if (
            den.size == 0
            or num.size == 0
            or not (np.all(np.isfinite(num)) and np.all(np.isfinite(den)))
        ):
            raise ParameterError(
                "channel_den", "finite, non-zero numerator and denominator", (list(num), list(den))
            )
        nc = den.size - 1
        if num.size - 1 > nc or (nc > 0 and num.size - 1 == nc):
            raise ParameterError(
                "channel_num", f"degree < {nc} (strictly proper) or a static gain", num.size - 1
            )
        num = num / den[0]
        den = den / den[0]
        if self.uses_input and nc == 0:
            raise ParameterError("uses_input", "False for a static-gain channel", True)
        d_samples = 0
        tau = 0.0
        if self.uses_input:
            q = self.input_delay / ts
            d_samples = math.floor(q + 1e-9)
            tau = max(0.0, self.input_delay - d_samples * ts)
            if tau < 1e-12 * ts:
                tau = 0.0
        k = len(freqs)
        n_off = 1 if self.include_offset else 0
        n = nc + 2 * k + n_off
        f = np.zeros((n, n))
        g = np.zeros(n)
        h = np.zeros(n)
        sel = np.zeros(2 * k + n_off)
        sel[0 : 2 * k : 2] = 1.0
        if n_off:
            sel[-1] = 1.0  # the offset state (last) adds to the channel input too
        if nc > 0:
            # controllable canonical form of num/den
            f[nc - 1, :nc] = -den[1:][::-1]
            for i in range(nc - 1):
                f[i, i + 1] = 1.0
            g[nc - 1] = 1.0
            numf = np.concatenate([np.zeros(nc - num.size), num])  # length nc, high first
            h[:nc] = numf[::-1]
            f[nc - 1, nc:] = sel  # harmonics add to the channel input
        else:
            h[nc:] = num[0] * sel  # static gain: y = g * sum s_i
        omegas = 2 * np.pi * np.array(freqs)
        for i, w in enumerate(omegas):
            j = nc + 2 * i
            # seed002 (5)-(7): s' = w c, c' = -w s
            f[j, j + 1] = w
            f[j + 1, j] = -w
        phi, gam_full = zoh(f, g, ts)
        if tau > 0:
            phi_rest, gb = zoh(f, g, ts - tau)
            _, gt = zoh(f, g, tau)
            ga = phi_rest @ gt
        else:
            gb = gam_full
            ga = np.zeros(n)
        ch = -2 * np.pi * self.channel_bandwidth_hz * (1 + 0.25 * np.arange(nc))
        poles_c = np.concatenate(
            [
                ch.astype(np.complex128),
                np.ravel(
                    [[-self.harmonic_decay + 1j * w, -self.harmonic_decay - 1j * w] for w in omegas]
                ),
                np.full(n_off, -self.harmonic_decay, dtype=np.complex128),
            ]
        )
        z_poles = np.exp(poles_c * ts)
        # current-estimator error dynamics (I - L H) Phi = I + T (F_delta - L_delta H Phi)
        f_delta = (phi - np.eye(n)) / ts
        l_delta = place_observer(f_delta, h @ phi, (z_poles - 1) / ts)
        gain = l_delta * ts
        object.__setattr__(self, "phi", phi)
        object.__setattr__(self, "gamma_a", np.ascontiguousarray(ga))
        object.__setattr__(self, "gamma_b", np.ascontiguousarray(gb))
        object.__setattr__(self, "h", h)
        object.__setattr__(self, "gain", gain)
        object.__setattr__(self, "lead_cos", np.cos(omegas * self.lead))
        object.__setattr__(self, "lead_sin", np.sin(omegas * self.lead))
        object.__setattr__(self, "channel_order", nc)
        object.__setattr__(self, "delay_samples", d_samples)

    @property
    def n_states(self) -> int:
        return self.channel_order + 2 * len(self.frequencies) + int(self.include_offset)

    def error_poles(self) -> NDArray[np.complex128]:
        """Eigenvalues of the discrete estimation-error dynamics ``(I - L H) Phi``."""
        n = self.n_states
        m = (np.eye(n) - np.outer(self.gain, self.h)) @ self.phi
        return np.asarray(np.linalg.eigvals(m), dtype=np.complex128)

    def with_frequencies(self, frequencies: tuple[float, ...]) -> DfoParams:
        """The same observer retuned to new frequencies (same count keeps the state)."""
        return replace(self, frequencies=tuple(frequencies))


@dataclass(frozen=True, eq=False)
class DfoState:
    """Posterior state estimate at the last processed sample, the input FIFO, the count."""

    x: F64
    u_hist: F64
    k: int


@dataclass(frozen=True, eq=False)
class DfoRecord:
    """Per-sample outputs.

    ``d_hat``: the disturbance estimate (sum of harmonics); ``compensation``: the same
    predicted ``lead`` ahead (what is subtracted from the command); ``amplitude`` and
    ``phase`` (n, K): each harmonic's :math:`A_i` and :math:`\\theta_i` of seed002 (5), the
    phase relative to ``t = k T`` with ``k`` counted from the observer's start;
    ``innovation``: ``y - H x_prior``; ``offset``: the constant part (0 without
    ``include_offset``).
    """

    d_hat: F64
    compensation: F64
    amplitude: F64
    phase: F64
    innovation: F64
    offset: F64


def _initial_state(params: DfoParams) -> DfoState:
    """Zero estimates, zero past inputs."""
    return DfoState(
        x=np.zeros(params.n_states),
        u_hist=np.zeros(params.delay_samples + 2 if params.uses_input else 0),
        k=0,
    )


class DfoModel(NamedTuple):
    """The discrete observer of seed002 (8)-(9) as the kernel takes it (read only)."""

    phi: F64  # (n, n) state transition Phi
    ga: F64  # G_a: input u[k-D-1]
    gb: F64  # G_b: input u[k-D]
    h: F64  # output row H
    gain: F64  # observer gain L
    nc: int  # the channel's own states before the harmonics
    omegas: F64  # each harmonic's angular frequency [rad/s]
    lc: F64  # each harmonic's compensation lead, cosine part
    ls: F64  # and sine part
    ts: float  # sample time [s]
    use_u: bool  # the model has the command as input
    has_off: bool  # the last state is a constant offset


class DfoOut(NamedTuple):
    """The kernel's per-sample outputs (filled in place): :class:`DfoRecord`'s fields."""

    d_hat: F64
    compensation: F64
    amplitude: F64
    phase: F64
    innovation: F64
    offset: F64


@njit(cache=True)
def _dfo_block(
    m: DfoModel, k0: int, x: F64, u_hist: F64, y: F64, out: DfoOut
) -> None:  # pragma: no cover
    """The observer ``m`` over the block ``y`` from sample ``k0``: posterior ``x`` updated
    in place, ``u_hist`` the delayed commands, ``out`` filled."""
    phi, ga, gb, h, gain, nc = m.phi, m.ga, m.gb, m.h, m.gain, m.nc
    omegas, lc, ls, ts, use_u, has_off = m.omegas, m.lc, m.ls, m.ts, m.use_u, m.has_off
    dh, comp, amp, ph, innov, off = (
        out.d_hat, out.compensation, out.amplitude, out.phase, out.innovation, out.offset
    )  # fmt: skip
    n = len(x)
    xp = np.empty(n)
    nh = len(omegas)
    # x- = Phi x + G_a u[k-D-1] + G_b u[k-D]; x = x- + L (y - H x-) (seed002 (8)-(9))
    for j in range(len(y)):
        # seed002 (8), discrete: prior from the last posterior and the delayed command
        for r in range(n):
            acc = 0.0
            for c in range(n):
                acc += phi[r, c] * x[c]
            if use_u:
                acc += ga[r] * u_hist[j] + gb[r] * u_hist[j + 1]
            xp[r] = acc
        # seed002 (9): y_hat = H x
        yh = 0.0
        for r in range(n):
            yh += h[r] * xp[r]
        e = y[j] - yh
        innov[j] = e
        for r in range(n):
            x[r] = xp[r] + gain[r] * e
        tk = (k0 + j) * ts
        total = 0.0
        tc = 0.0
        for i in range(nh):
            s = x[nc + 2 * i]
            c = x[nc + 2 * i + 1]
            total += s
            tc += s * lc[i] + c * ls[i]
            amp[j, i] = math.sqrt(s * s + c * c)
            th = math.atan2(s, c) - omegas[i] * tk
            ph[j, i] = math.atan2(math.sin(th), math.cos(th))
        o = x[n - 1] if has_off else 0.0
        off[j] = o
        dh[j] = total + o
        comp[j] = tc + o


def _step(params: DfoParams, state: DfoState, y: ArrayLike) -> tuple[DfoState, DfoRecord]:
    """Process a block of measurements ``y``.

    With ``uses_input`` the block may hold at most ``D + 1`` samples (``D`` whole samples
    of input delay) and the block's commands must be handed over with :meth:`Dfo.apply`
    before the next step.
    """
    ya = np.ascontiguousarray(y, dtype=np.float64)
    if ya.ndim != 1 or ya.size < 1:
        raise ParameterError("y", "a non-empty 1-D block", ya.shape)
    n = ya.size
    if params.uses_input:
        big_d = params.delay_samples
        if n > big_d + 1:
            raise ParameterError("y", f"a block of at most {big_d + 1} samples (delay + 1)", n)
        if state.u_hist.size != big_d + 2:
            raise ParameterError(
                "state",
                "the previous block's commands applied first",
                f"{big_d + 2 - state.u_hist.size} commands missing",
            )
    x = state.x.copy()
    nh = len(params.frequencies)
    out = DfoOut(np.empty(n), np.empty(n), np.empty((n, nh)), np.empty((n, nh)), np.empty(n),
                 np.empty(n))  # fmt: skip
    model = DfoModel(
        phi=params.phi,
        ga=params.gamma_a,
        gb=params.gamma_b,
        h=params.h,
        gain=params.gain,
        nc=params.channel_order,
        omegas=2 * np.pi * np.asarray(params.frequencies),
        lc=params.lead_cos,
        ls=params.lead_sin,
        ts=params.sample_time,
        use_u=params.uses_input,
        has_off=params.include_offset,
    )
    _dfo_block(model, state.k, x, state.u_hist, ya, out)
    u_hist = state.u_hist[n:].copy() if params.uses_input else state.u_hist
    return (
        DfoState(x=x, u_hist=u_hist, k=state.k + n),
        DfoRecord(**out._asdict()),
    )


def _apply(params: DfoParams, state: DfoState, commands: ArrayLike) -> DfoState:
    """Hand over the commands [input unit] applied during the last processed block."""
    u = np.ascontiguousarray(commands, dtype=np.float64)
    if not params.uses_input:
        raise ParameterError("commands", "no commands (the observer has no input)", u.shape)
    need = params.delay_samples + 2 - state.u_hist.size
    if u.ndim != 1 or u.size != need:
        raise ParameterError("commands", f"a 1-D block of {need} samples", u.shape)
    return DfoState(x=state.x, u_hist=np.concatenate([state.u_hist, u]), k=state.k)


class Dfo:
    """The harmonic observer of ``params`` (the estimator contract: :meth:`initial_state`,
    :meth:`step`; :meth:`apply` hands over the commands of an observer with an input).

    Examples
    --------
    >>> obs = Dfo(DfoParams(frequencies=(100.0,), sample_time=4e-4, channel_num=(1.0,),
    ...                     channel_den=(1.0,)))  # doctest: +SKIP
    >>> state, rec = obs.step(obs.initial_state(), y)  # doctest: +SKIP
    """

    def __init__(self, params: DfoParams) -> None:
        self.params = params

    def initial_state(self) -> DfoState:
        """Zero estimates, zero past inputs."""
        return _initial_state(self.params)

    def step(self, state: DfoState, y: ArrayLike) -> tuple[DfoState, DfoRecord]:
        """Process a block of measurements ``y`` (see :func:`_step`)."""
        return _step(self.params, state, y)

    def apply(self, state: DfoState, commands: ArrayLike) -> DfoState:
        """Hand over the commands applied during the last processed block."""
        return _apply(self.params, state, commands)


__all__ = [
    "Dfo",
    "DfoParams",
    "DfoRecord",
    "DfoState",
    "place_observer",
]
