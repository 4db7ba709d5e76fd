r"""One-sided 95 % confidence bounds, the one place every reproduction takes them from.

A target is one-sided ("detection >= 99 %", "<= 0.1 false alarms per hour", "p95 delay
<= 2 revolutions"), so its check uses the one-sided bound on the side the target
limits, at ``conf`` (95 %):

* a share ``k / n`` (detections): the exact **Clopper-Pearson** bound,
  :math:`p_{lo} = B^{-1}(1 - c;\ k, n - k + 1)` below and
  :math:`p_{hi} = B^{-1}(c;\ k + 1, n - k)` above (``scipy.stats.beta``). With no miss
  :math:`p_{lo} = (1 - c)^{1/n}`: ``>= 99 %`` needs :func:`events_for` (0.99) = **299
  events with no miss**;
* a count ``k`` in an exposure ``T`` (false alarms per hour): the exact Poisson
  (**Garwood**) bound, :math:`\lambda_{hi} = \chi^2_{c}(2k + 2) / 2T`; with none,
  :math:`-\ln(1 - c) / T`: ``<= 1 per 10 h`` needs :func:`hours_for` (0.1) = **30 h with
  none**;
* a quantile (a p95 delay): the distribution-free upper bound, the smallest order
  statistic :math:`x_{(u)}` with :math:`P(\mathrm{Binom}(n, q) < u) \ge c`.

The pair :func:`proportion_bounds` gives both one-sided bounds of a share (together a
two-sided 90 % interval): the one a target looks at is the one-sided 95 % bound.
"""

from __future__ import annotations

import math

#: the one confidence level of every reproduction's bounds (one-sided)
CONF = 0.95


def _check_share(k: int, n: int) -> None:
    if n < 1 or not 0 <= k <= n:
        raise ValueError(f"a share needs 0 <= k <= n and n >= 1; found k={k}, n={n}")


def proportion_lower(k: int, n: int, conf: float = CONF) -> float:
    """One-sided lower Clopper-Pearson bound of a share ``k / n`` (0 when ``k`` is 0)."""
    from scipy.stats import beta

    _check_share(k, n)
    if k == 0:
        return 0.0
    if k == n:
        return float((1.0 - conf) ** (1.0 / n))
    return float(beta.ppf(1.0 - conf, k, n - k + 1))


def proportion_upper(k: int, n: int, conf: float = CONF) -> float:
    """One-sided upper Clopper-Pearson bound of a share ``k / n`` (1 when ``k`` is ``n``)."""
    from scipy.stats import beta

    _check_share(k, n)
    if k == n:
        return 1.0
    if k == 0:
        return float(1.0 - (1.0 - conf) ** (1.0 / n))
    return float(beta.ppf(conf, k + 1, n - k))


def proportion_bounds(k: int, n: int, conf: float = CONF) -> tuple[float, float]:
    """``(lower, upper)``: each the one-sided ``conf`` bound of the share ``k / n``."""
    return proportion_lower(k, n, conf), proportion_upper(k, n, conf)


def rate_upper(k: int, exposure: float, conf: float = CONF) -> float:
    """One-sided upper Garwood bound of a rate: ``k`` counts in ``exposure`` (e.g. hours)."""
    from scipy.stats import chi2

    if k < 0 or not exposure > 0.0:
        raise ValueError(f"a rate needs k >= 0 and exposure > 0; found k={k}, {exposure=}")
    return float(chi2.ppf(conf, 2 * k + 2) / 2.0 / exposure)


def rate_lower(k: int, exposure: float, conf: float = CONF) -> float:
    """One-sided lower Garwood bound of a rate (0 when ``k`` is 0)."""
    from scipy.stats import chi2

    if k < 0 or not exposure > 0.0:
        raise ValueError(f"a rate needs k >= 0 and exposure > 0; found k={k}, {exposure=}")
    return 0.0 if k == 0 else float(chi2.ppf(1.0 - conf, 2 * k) / 2.0 / exposure)


def quantile_upper(x: list[float], q: float, conf: float = CONF) -> float:
    """Distribution-free one-sided upper bound of the ``q`` quantile of ``x``: the smallest
    order statistic ``x_(u)`` with ``P(Binom(n, q) < u) >= conf`` (inf if ``x`` is too short
    to bound it, NaN if empty)."""
    from scipy.stats import binom

    v = sorted(x)
    if not v:
        return math.nan
    u = int(binom.ppf(conf, len(v), q))
    return float(v[u]) if u < len(v) else math.inf


def events_for(target: float, conf: float = CONF) -> int:
    """Events needed, with no miss, for the lower bound of a share to reach ``target``:
    the smallest ``n`` with ``(1 - conf) ** (1 / n) >= target`` (299 for 0.99)."""
    if not 0.0 < target < 1.0:
        raise ValueError(f"target share must lie in (0, 1); found {target}")
    return math.ceil(math.log(1.0 - conf) / math.log(target) - 1e-12)


def hours_for(rate: float, conf: float = CONF) -> float:
    """Exposure needed, with no count, for the upper bound of a rate to reach ``rate``:
    ``-ln(1 - conf) / rate`` (29.96 h for 0.1 per hour)."""
    if not rate > 0.0:
        raise ValueError(f"rate must be > 0; found {rate}")
    return -math.log(1.0 - conf) / rate
