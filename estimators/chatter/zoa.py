r"""Milling stability lobes by the zero-order approximation (Altintas & Budak, 1995).

The directional matrix :math:`A(t)` of :mod:`common.cut_geometry` is replaced by its
average :math:`A_0` over a tooth period (the zero-order term of its Fourier series).
With :math:`\Phi(i\omega)` the receptance of the relative displacement
(:meth:`ModalModel.frf`), a vibration at :math:`\omega` is sustained when

.. math::

    \det\big[I + a\,(1 - e^{-i\omega\tau})\,A_0\Phi(i\omega)\big] = 0
    \quad\Longleftrightarrow\quad 1 + a(1-e^{-i\omega\tau})\Lambda = 0

for an eigenvalue :math:`\Lambda` of :math:`A_0\Phi(i\omega)` (Altintas & Budak,
CIRP Annals 44 (1995), their eq. (11) in this project's sign convention). For a real depth
:math:`a` the product :math:`\Lambda(1-e^{-i\omega\tau})` must be real and negative,
which needs :math:`\mathrm{Re}\,\Lambda < 0` and gives

.. math::

    a_{lim} = -\frac{1}{2\,\mathrm{Re}\,\Lambda}, \qquad
    \omega\tau = 2\arg\Lambda - \pi + 2k\pi, \quad k = 0, 1, \dots

(:math:`\arg\Lambda` taken in :math:`(\pi/2, 3\pi/2)`), the spindle speed
:math:`60/(N\tau)` rpm. Each :math:`k` is one lobe; scanning the chatter frequency
draws it. The boundary at a speed is the lowest lobe there.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from common.arrays import F64
from common.cut_geometry import CutGeometry
from common.modes import ModalModel
from estimators.errors import ParameterError, require_positive


@dataclass(frozen=True)
class ZoaLobe:
    """One lobe: spindle speed, critical depth and chatter frequency along the scan."""

    k: int
    rpm: F64
    depth: F64
    freq_hz: F64


def zoa_lobes(
    modal: ModalModel,
    cut: CutGeometry,
    *,
    freq_range: tuple[float, float] | None = None,
    n_freq: int = 4000,
    max_lobes: int = 40,
) -> list[ZoaLobe]:
    """The lobes of the zero-order approximation, ``max_lobes`` per eigenvalue branch.

    ``freq_range`` [Hz] is the chatter-frequency scan (default: 0.3x the lowest mode to
    3x the highest).
    """
    if int(n_freq) != n_freq or n_freq < 10:
        raise ParameterError("n_freq", "an integer >= 10", n_freq)
    lo, hi = freq_range or (
        0.3 * min(m.freq_hz for m in modal.modes),
        3.0 * modal.highest_hz,
    )
    if not (0.0 < lo < hi and math.isfinite(hi)):
        raise ParameterError("freq_range", "0 < low < high [Hz]", freq_range)
    freqs = np.linspace(lo, hi, int(n_freq))
    a0 = cut.mean_directional()
    lam = np.linalg.eigvals(a0[None, :, :] @ modal.frf_many(freqs))  # (n, 2)
    lam = np.sort_complex(lam)  # a stable branch order along the scan
    lobes = []
    for b in range(lam.shape[1]):
        lb = lam[:, b]
        ok = lb.real < 0.0
        if not np.any(ok):
            continue
        # Altintas-Budak (1995) eq. (11): a_lim = -1 / (2 Re Lambda); nan where Re >= 0
        with np.errstate(divide="ignore"):
            depth = np.where(ok, -1.0 / (2.0 * lb.real), np.nan)
        # arg in (pi/2, 3 pi/2): omega tau = 2 arg - pi (+ 2 k pi)
        theta0 = 2.0 * np.mod(np.angle(lb), 2.0 * np.pi) - np.pi
        for k in range(int(max_lobes)):
            tau = (theta0 + 2.0 * np.pi * k) / (2.0 * np.pi * freqs)
            with np.errstate(divide="ignore"):
                rpm = np.where(ok, 60.0 / (cut.n_flutes * tau), np.nan)
            lobes.append(ZoaLobe(k, rpm, depth, freqs))
    return lobes


def zoa_boundary(lobes: list[ZoaLobe], rpm: float) -> tuple[float, float]:
    """The lowest critical depth [m] at ``rpm`` over all lobes, and its chatter frequency
    [Hz] (``inf, nan`` when no lobe reaches this speed)."""
    r = require_positive("rpm", rpm)
    best = (math.inf, math.nan)
    for lobe in lobes:
        x = lobe.rpm
        # every segment of the lobe's curve that crosses this speed
        # (a segment with an end outside Re Lambda < 0 is nan and never crosses)
        s = (x[:-1] - r) * (x[1:] - r) <= 0.0
        for i in np.flatnonzero(s):
            dx = x[i + 1] - x[i]
            w = 0.0 if dx == 0.0 else (r - x[i]) / dx
            d = lobe.depth[i] + w * (lobe.depth[i + 1] - lobe.depth[i])
            if d < best[0]:
                f = lobe.freq_hz[i] + w * (lobe.freq_hz[i + 1] - lobe.freq_hz[i])
                best = (float(d), float(f))
    return best


def zoa_chart(modal: ModalModel, cut: CutGeometry, rpms: F64, **kw: object) -> tuple[F64, F64]:
    """ZOA boundary depth [m] and chatter frequency [Hz] at each speed of ``rpms``."""
    lobes = zoa_lobes(modal, cut, **kw)  # type: ignore[arg-type]
    out = np.array([zoa_boundary(lobes, float(r)) for r in np.asarray(rpms, dtype=float)])
    return out[:, 0], out[:, 1]


__all__ = ["ZoaLobe", "zoa_boundary", "zoa_chart", "zoa_lobes"]
