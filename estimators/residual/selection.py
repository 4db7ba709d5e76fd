r"""Effect selection from blocked cross-validation (shared by the rigid and two-inertia analyses).

The decision whether a candidate family explains something the model lacks is taken on
the *fitting part* of the record (everything before the held-out end, which stays
untouched for the final report figure):

1. **Blocked K-fold cross-validation.** The fitting rows are cut into ``folds``
   contiguous folds. For fold k the model is fitted on the other folds minus ``guard``
   rows on each side of fold k (the filters' memory: a row next to the fold shares its
   filtered noise) and predicts fold k. The candidate's shape parameters (period,
   frequency, Stribeck velocity...) are searched again on those training rows only, so
   the search never sees the rows it is scored on.
2. **Scored where the candidate acts.** The candidate's *support* is where its fitted
   term (from the training rows) is at least ``support_level`` of its 99th percentile:
   a Stribeck term acts in its low-speed band, a direction-dependent friction where the
   axis moves. Per fold, the effect size is

   .. math::

       d_k = \frac{\overline{e_{0}^2} - \overline{e_{1}^2}\big|_{\text{support}}}
                  {\overline{e_{0}^2}\big|_{\text{fold}}}

   the mean-square error removed on the support, relative to the current model's mean
   square over the whole fold (the noise floor of this record). A local effect is not
   diluted by the rows where it is zero, and the size is relative to the floor, so it
   does not shrink as the record grows.
3. **Tested across groups.** The support rows are cut into ``blocks`` groups in time
   and the per-group reductions are tested for a positive centre with the one-sided
   Wilcoxon signed-rank test (``test="signed_rank"``, the default; Student's t as
   ``"t"``, and ``"t_or_rank"``, the smaller p of the two times two, are kept for
   comparison). p-values of all candidates of a round are corrected by Holm's
   step-down method (family-wise error ``alpha``; uniformly more powerful than
   Bonferroni).

   Why a rank test: the gain of an effect that acts at events (a delay or a force-loop
   lag where the effort changes quickly, a Stribeck band at a few reversals) sits in
   the few groups holding the events, e.g. four groups of 20 at 8-10 floors and the
   other 16 at +0.01 ... +0.3. Student's t divides the mean by that spread: it missed 5
   of 20 seeds of a 10 s record with a 10 ms drive delay (p 0.007-0.024 against Holm's
   0.0056) although the delay removed 1.7-6.5 floors; the signed-rank test counts that
   nearly every group improves (p about 1e-5; 20 of 20). On the first half of the real
   EMPS record it accepts four effects where t accepted one (cycles 3-4 predicted at
   2.19 % instead of 4.13 %). The pair ``t_or_rank`` pays a factor two for its second
   test and accepted nothing there. What the rank test gives up: a gain that varies
   smoothly in size with a few groups slightly negative (an amplitude-modulated torque
   where its envelope passes zero) is seen better by the mean (p 0.0016 by t, 0.0077 by
   rank on a 23 Hz carrier modulated at 0.7 Hz, which is then reported as unexplained
   rather than half-fitted by a stationary harmonic). Under the null (the candidate
   only fits noise) the out-of-fold reductions are centred at or below zero, which
   keeps the test at or below its level.
4. **A minimum effect size.** A candidate must also remove at least ``min_effect`` of
   the floor on average (:math:`\bar d \ge` 0.25 by default): with a long record the
   t-test alone accepts any tiny systematic mismatch (the observer's own discretisation
   error); the size criterion does not move with the record length.

Among the accepted candidates the one with the largest total cross-validated reduction
is chosen; candidates whose fitted terms on this record are nearly the same signal as
the chosen one (correlation >= ``same_signal``) and explain nearly as much are reported
as *indistinguishable here*, with the excitation that would separate them.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TypedDict

import numpy as np
from numpy.typing import NDArray
from scipy import stats

from common.arrays import F64
from estimators.errors import ParameterError, require_in


@dataclass(frozen=True)
class SelectionParams:
    """Settings of the cross-validated selection (see the module docstring).

    Parameters
    ----------
    folds : int
        Contiguous folds of the fitting part (>= 3).
    blocks : int
        Groups of support rows of the t-test.
    alpha : float
        Family-wise error of one round (Holm over the round's candidates).
    min_effect : float
        Least mean fraction of the floor (the fold's mean square error) removed on the
        candidate's support.
    support_level : float
        Fraction of the fitted term's 99th percentile above which a row is support.
    same_signal : float
        Correlation of two fitted terms above which they are the same signal here.
    tie : float
        Fraction of the best total reduction within which a same-signal candidate is
        reported as indistinguishable.
    test : str
        Test of the per-group reductions: ``"signed_rank"`` (Wilcoxon, the default),
        ``"t"`` (Student) or ``"t_or_rank"`` (the smaller p of the two, times two).
    """

    folds: int = 5
    blocks: int = 20
    alpha: float = 0.05
    min_effect: float = 0.25
    support_level: float = 0.1
    same_signal: float = 0.95
    tie: float = 0.15
    test: str = "signed_rank"

    def __post_init__(self) -> None:
        if not isinstance(self.folds, int) or not 3 <= self.folds <= 20:
            raise ParameterError("folds", "an integer in [3, 20]", self.folds)
        if not isinstance(self.blocks, int) or not 3 <= self.blocks <= 100:
            raise ParameterError("blocks", "an integer in [3, 100]", self.blocks)
        require_in("alpha", self.alpha, 1e-6, 0.5)
        require_in("min_effect", self.min_effect, 0.0, 10.0)
        require_in("support_level", self.support_level, 0.0, 1.0)
        require_in("same_signal", self.same_signal, 0.0, 1.0)
        require_in("tie", self.tie, 0.0, 1.0)
        if self.test not in TESTS:
            raise ParameterError("test", f"one of {list(TESTS)}", self.test)


@dataclass(frozen=True)
class Fold:
    """One fold over the fitting part: validation rows ``a .. b - 1``; training rows are
    the fitting rows outside ``lo .. hi - 1`` (the fold and its guards)."""

    train: NDArray[np.bool_]
    val: NDArray[np.bool_]
    a: int = 0
    b: int = 0
    lo: int = 0
    hi: int = 0
    n_fit: int = 0


def make_folds(n: int, n_fit: int, folds: int, guard: int) -> list[Fold]:
    """``folds`` contiguous folds over rows ``0 .. n_fit - 1`` of ``n`` rows.

    Training rows of fold k: the other fitting rows except ``guard`` rows on each side
    of fold k. Rows from ``n_fit`` on (the held-out end) are in neither.
    """
    edges = np.linspace(0, n_fit, folds + 1).round().astype(int)
    out = []
    for k in range(folds):
        a, b = int(edges[k]), int(edges[k + 1])
        val = np.zeros(n, dtype=bool)
        val[a:b] = True
        train = np.zeros(n, dtype=bool)
        train[:n_fit] = True
        lo, hi = max(a - guard, 0), min(b + guard, n_fit)
        train[lo:hi] = False
        out.append(Fold(train, val, a, b, lo, hi, n_fit))
    return out


def support(term_train: F64, term_all: F64, level: float) -> NDArray[np.bool_]:
    """Rows where ``|term_all|`` is at least ``level`` of the 99th percentile of
    ``|term_train|`` (the candidate's fitted term on its training rows)."""
    ref = float(np.percentile(np.abs(term_train), 99.0)) if len(term_train) else 0.0
    if not ref > 0.0:
        return np.zeros(len(term_all), dtype=bool)
    return np.asarray(np.abs(term_all) >= level * ref)


@dataclass(frozen=True)
class OutOfFold:
    """Out-of-fold squared errors over the fitting rows (each row predicted by the model
    fitted without its fold), before and after the candidate, and its support."""

    sq0: F64
    sq1: F64
    supp: NDArray[np.bool_]


@dataclass(frozen=True)
class Verdict:
    """The test of one candidate."""

    mean_effect: float
    t_stat: float
    p_value: float
    folds_used: int  # blocks of support rows tested
    total_reduction: float  # out-of-fold mean-square reduction over all fitting rows
    support_fraction: float


#: tests of the per-group reductions
TESTS = ("signed_rank", "t", "t_or_rank")


def verdict(oof: OutOfFold, blocks: int, min_rows: int = 5, test: str = "signed_rank") -> Verdict:
    """Effect size and one-sided test (``test``) of the out-of-fold reduction on the support.

    The support rows (in time order) are cut into ``blocks`` groups of equal count; per
    group :math:`d_b = (\\overline{e_0^2} - \\overline{e_1^2}) / \text{floor}`, with the
    floor the current model's out-of-fold mean square over all fitting rows. A local
    effect (a Stribeck band visited at a few reversals) gets as many samples of the test
    as a global one.
    """
    floor = float(np.mean(oof.sq0)) if len(oof.sq0) else 0.0
    red = float(np.mean(oof.sq0 - oof.sq1)) if len(oof.sq0) else 0.0
    idx = np.flatnonzero(oof.supp)
    frac = len(idx) / max(len(oof.sq0), 1)
    nb = min(blocks, len(idx) // max(min_rows, 1))
    if nb < 3 or not floor > 0.0:
        return Verdict(math.nan, math.nan, 1.0, nb, red, frac)
    diff = (oof.sq0 - oof.sq1)[idx] / floor
    d = np.array([float(np.mean(g)) for g in np.array_split(diff, nb)])
    mean = float(np.mean(diff))
    sd = float(np.std(d, ddof=1))
    if sd == 0.0:
        t = math.inf if mean > 0 else (0.0 if mean == 0 else -math.inf)
    else:
        t = float(np.mean(d)) / (sd / math.sqrt(nb))
    p_t = float(stats.t.sf(t, nb - 1)) if math.isfinite(t) else (0.0 if t > 0 else 1.0)
    # Wilcoxon signed-rank over the groups (exact for <= 50 groups without ties)
    p_w = 1.0
    if test != "t" and np.any(d):
        p_w = float(stats.wilcoxon(d, alternative="greater", method="auto").pvalue)
    if test == "t":
        p = p_t
    elif test == "signed_rank":
        p = p_w
    else:  # either test, each at half the level (Bonferroni over the two)
        p = min(1.0, 2.0 * min(p_t, p_w))
    return Verdict(mean, t, p, nb, red, frac)


def holm(p_values: list[float], alpha: float) -> list[bool]:
    """Holm's step-down rejections of the hypotheses with these p-values."""
    order = sorted(range(len(p_values)), key=lambda i: p_values[i])
    out = [False] * len(p_values)
    m = len(p_values)
    for rank, i in enumerate(order):
        if p_values[i] <= alpha / (m - rank):
            out[i] = True
        else:
            break
    return out


def correlation(a: F64, b: F64) -> float:
    """|cosine| of two fitted terms (uncentred: a constant and a constant are equal)."""
    na, nb = float(np.linalg.norm(a)), float(np.linalg.norm(b))
    if na == 0.0 or nb == 0.0:
        return 0.0
    return abs(float(a @ b)) / (na * nb)


#: where each family acts (the "support" in words)
SUPPORT_TEXT: dict[str, str] = {
    "offset": "everywhere, at rest too",
    "coulomb_asymmetry": "while moving, differently per direction",
    "stribeck": "at low speed, decaying with speed",
    "position_periodic": "periodic in the load position",
    "torque_ripple": "periodic in the motor angle",
    "backlash": "where the transmission's twist changes sign",
    "inertia": "in proportion to the acceleration",
    "viscous": "in proportion to the speed",
    "harmonic": "periodic in time",
    "drift": "growing with time",
    "delay": "where the effort changes quickly",
    # the real-drive families (estimators.residual.families)
    "position_friction": "while moving, varying smoothly along the travel, per direction",
    "position_harmonics": "periodic in the position, with a part that follows the direction",
    "drive_delay": "where the whole effort changes quickly (it acts late)",
    "force_lag": "where the effort changes quickly (a first-order lag of the force loop)",
}

#: what tells a pure delay from a first-order lag (both lag families against force_lag)
_DELAY_OR_LAG = (
    "a step or a square wave added to the command: a pure delay shifts the whole "
    "response, a first-order lag rounds it"
)
#: excitation that separates two families, by pair
SEPARATING: dict[frozenset[str], str] = {
    frozenset({"offset", "coulomb_asymmetry"}): (
        "rests where the load really sticks (no vibration through zero speed, e.g. an "
        "air move without cutting force, dwell of a second or more): an offset acts at "
        "rest, friction only while moving; or one direction only at several speeds"
    ),
    frozenset({"delay", "force_lag"}): _DELAY_OR_LAG,
    frozenset({"drive_delay", "force_lag"}): _DELAY_OR_LAG,
    frozenset({"stribeck", "coulomb_asymmetry"}): (
        "plateaus at several low speeds in each direction: a Stribeck term decays with "
        "speed, direction-dependent friction does not"
    ),
    frozenset({"stribeck", "offset"}): (
        "plateaus at several low speeds in each direction and rests: a Stribeck term "
        "changes sign with the direction and decays with speed"
    ),
    frozenset({"position_periodic", "torque_ripple"}): (
        "moves where the motor and load angles drift apart (a changing twist or gear "
        "position): ripple follows the motor angle, the load torque the load position"
    ),
    frozenset({"position_periodic", "harmonic"}): (
        "plateaus at several speeds: a position-periodic torque changes its frequency "
        "with speed, a harmonic in time does not"
    ),
    frozenset({"torque_ripple", "harmonic"}): (
        "plateaus at several speeds: torque ripple changes its frequency with speed, a "
        "harmonic in time does not"
    ),
    frozenset({"drift", "offset"}): "a longer record or a repeated motion later in time",
    frozenset({"viscous", "coulomb_asymmetry"}): (
        "plateaus at several speeds in each direction: viscous friction grows with "
        "speed, Coulomb friction does not"
    ),
}


def separating_excitation(a: str, b: str) -> str:
    """The excitation that would tell families ``a`` and ``b`` apart."""
    key = frozenset({a, b})
    if key in SEPARATING:
        return SEPARATING[key]
    return (
        f"motion where they differ: {a} acts {SUPPORT_TEXT.get(a, '?')}, "
        f"{b} {SUPPORT_TEXT.get(b, '?')}"
    )


class Ambiguity(TypedDict):
    """An ``indistinguishable`` entry of a report (:func:`ambiguity`)."""

    families: list[str]
    installed: str
    why: str
    excitation: str


def ambiguity(names: list[str], installed: str, same_signal: float) -> Ambiguity:
    """The ``indistinguishable`` entry of a report: the families, the one installed (it
    carries the signal as well as the others here), why, and what would separate them."""
    others = [n for n in names if n != installed]
    return {
        "families": list(names),
        "installed": installed,
        "why": (
            f"their fitted terms are the same signal on this record (correlation >= "
            f"{same_signal:g}) and remove the same error; "
            + "; ".join(f"{n} acts {SUPPORT_TEXT.get(n, '?')}" for n in names)
        ),
        # one text per separating excitation (a pair of lag families shares one)
        "excitation": "; ".join(dict.fromkeys(separating_excitation(installed, o) for o in others)),
    }
