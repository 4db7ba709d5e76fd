r"""The residual engine: one greedy selection over a residual model (rigid or two-inertia).

A *model* (:class:`ResidualModel`) knows its nominal fit, its family registry, how to
search a family's shape parameters on some rows, the columns of a family, how to fit
the current model plus a candidate on the fitting part and out of each fold, and what
its result holds. :func:`analyse` owns what is common: the rounds, the screening and
the shape search again inside each training fold, Holm over a round's candidates, the
minimum effect size, ties and the ambiguity report (the rule and its reasons:
:mod:`estimators.residual.selection`, docs/residual-selection.md). The two models are
:class:`estimators.residual.rigid.RigidModel` (IDIM-LS of a rigid axis) and
:class:`estimators.residual.two_inertia.TwoInertiaModel` (the cutting force observer).

Per round, every family not yet selected is scored: its shape is searched on the
residual of the whole fitting part; a family that adds no column the current model
lacks, or whose shape is not found, is reported and skipped; the others get their
out-of-fold verdict. A shaped family that passes a screening (half the minimum effect,
p < 0.5, with the shape of the whole fitting part) is scored again with its shape
searched inside each training fold, so the search never sees the rows it is scored on.
The held-out end of the record takes no part in the selection: it is the report
figure (``rms_*``, ``relerr_*``, the candidates' ``score``).

Sampling-rate-dependent choices (filter cut-offs, decimation, the least record length,
which families a record can identify) belong to the model and its settings, never to
this loop.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field, replace
from typing import Any, Generic, Protocol, TypeVar

import numpy as np

from common.arrays import F64
from estimators.errors import ParameterError, require_in
from estimators.residual.selection import (
    Ambiguity,
    Fold,
    OutOfFold,
    SelectionParams,
    Verdict,
    ambiguity,
    correlation,
    holm,
    make_folds,
    verdict,
)

Shape = dict[str, float]


@dataclass(frozen=True)
class ResidualParams:
    """Settings of a residual analysis (either model).

    Parameters
    ----------
    holdout_fraction : float
        Fraction of the record, at its end, held out for the report figure (0.05 ... 0.7).
    blocks : int
        Sets the least record length (40 rows of the selection per block, >= 3).
    max_effects : int, optional
        Most effects added (None: the model's cap).
    families : tuple of str, optional
        Families offered (None: every family of the model's registry).
    selection : SelectionParams
        The cross-validated decision rule.
    """

    holdout_fraction: float = 0.3
    blocks: int = 10
    max_effects: int | None = None
    families: tuple[str, ...] | None = None
    selection: SelectionParams = field(default_factory=SelectionParams)

    def __post_init__(self) -> None:
        require_in("holdout_fraction", self.holdout_fraction, 0.05, 0.7)
        if not isinstance(self.blocks, int) or self.blocks < 3:
            raise ParameterError("blocks", "an integer >= 3", self.blocks)
        if self.max_effects is not None and (
            not isinstance(self.max_effects, int) or self.max_effects < 0
        ):
            raise ParameterError("max_effects", "an integer >= 0", self.max_effects)


class FamilyEntry(Protocol):
    """What the engine asks of an effect family of any model's registry (the rigid
    model's :class:`estimators.residual.families.Family`, the two-inertia model's
    :class:`estimators.residual.two_inertia.TwoInertiaFamily`): whether it has a shape to search
    again inside each training fold."""

    @property
    def shaped(self) -> bool: ...


def offered_families(
    params: ResidualParams, registry: Mapping[str, FamilyEntry]
) -> tuple[str, ...]:
    """The families of ``params`` (default: the whole registry), checked against it."""
    fams = tuple(registry) if params.families is None else params.families
    unknown = [f for f in fams if f not in registry]
    if unknown:
        raise ParameterError("families", f"names among {', '.join(registry)}", unknown[0])
    return fams


def effect_cap(params: ResidualParams, default: int, registry: Mapping[str, FamilyEntry]) -> int:
    """The most effects of ``params`` (default: the model's cap), at most the registry's size."""
    cap = default if params.max_effects is None else params.max_effects
    if not 0 <= cap <= len(registry):
        raise ParameterError("max_effects", f"an integer in [0, {len(registry)}]", cap)
    return cap


@dataclass(frozen=True)
class Effect:
    """A selected or candidate effect: family, shape parameters, column names and (once
    fitted) one coefficient per column."""

    name: str
    shape: Mapping[str, float]
    columns: tuple[str, ...] = ()
    coef: tuple[float, ...] = ()


@dataclass(frozen=True)
class CandidateScore:
    """One candidate at the round it was last scored."""

    name: str
    params: dict[str, float]
    rms_before: float
    rms_after: float
    score: float
    t_stat: float
    selected: bool
    note: str = ""
    cv_effect: float = math.nan  # mean per-fold share of the floor removed on the support
    p_value: float = math.nan  # one-sided across folds (before Holm)
    folds_used: int = 0  # folds with enough support
    support_fraction: float = math.nan  # mean share of validation rows on the support
    passed: bool = False  # passed Holm and the minimum effect size at its last round


@dataclass(frozen=True, eq=False)
class ResidualResult:
    """Outcome of :func:`analyse`, for either model.

    ``rms_*`` and ``relerr_*`` are on the held-out rows (the model's measure: the rigid
    model's decimated effort, the observer's two channels); ``f_hat_*`` are the model
    efforts at every input sample; ``*_dec`` a display series of the residual;
    ``hold_*`` the per-row squared errors on the held-out rows (``hold_sq_force_*``:
    the force channel alone) and the speed there. ``details`` holds the model's own
    report entries (per-channel figures, the observer's terms).
    """

    kind: str
    model: str
    names_before: tuple[str, ...]
    theta_before: F64
    names_after: tuple[str, ...]
    theta_after: F64
    effects: tuple[Effect, ...]
    candidates: tuple[CandidateScore, ...]
    holdout_start: float
    holdout_stop: float
    rms_before: float
    rms_after: float
    relerr_before: float
    relerr_after: float
    unexplained: tuple[dict[str, float | str], ...]
    f_hat_before: F64
    f_hat_after: F64
    t_dec: F64
    residual_before_dec: F64
    residual_after_dec: F64
    q_dec: F64
    qd_dec: F64
    not_offered: Mapping[str, str] = field(default_factory=dict)
    reference: str = ""
    details: Mapping[str, Any] = field(default_factory=dict)
    indistinguishable: tuple[Ambiguity, ...] = ()
    selection: SelectionParams = field(default_factory=SelectionParams)
    hold_sq_before: F64 = field(default_factory=lambda: np.zeros(0))
    hold_sq_after: F64 = field(default_factory=lambda: np.zeros(0))
    hold_speed: F64 = field(default_factory=lambda: np.zeros(0))
    hold_sq_force_before: F64 = field(default_factory=lambda: np.zeros(0))
    hold_sq_force_after: F64 = field(default_factory=lambda: np.zeros(0))
    #: each selected effect's fitted term on the display rows (``*_dec``), to draw it
    terms_dec: Mapping[str, F64] = field(default_factory=dict)


S = TypeVar("S")  # a fitted model structure (the model's own state)
C = TypeVar("C")  # a candidate's columns over the record
B = TypeVar("B")  # the current model fitted without one fold


@dataclass(frozen=True, eq=False)
class Extension(Generic[S, C]):
    """The current model plus one candidate, fitted on the fitting part."""

    state: S
    columns: C  # the candidate's columns (scored out of fold)
    added: int  # candidate columns not spanned by the current model
    ncols: int  # the candidate's columns (fewer wins a tie)
    term: F64  # the candidate's fitted term (ties: same signal or not)
    params: dict[str, float]  # shape and coefficients, as reported


@dataclass(frozen=True)
class Rows:
    """The rows the selection works on: ``n`` in all, ``split`` fitting rows first (the
    rest is the held-out end), ``guard`` rows left out of training around a fold."""

    n: int
    split: int
    guard: int


class ResidualModel(Protocol[S, C, B]):
    """A nominal model and its effect families, as :func:`analyse` uses them."""

    kind: str

    @property
    def families(self) -> Mapping[str, FamilyEntry]:
        """The family registry of this model (name -> family; its ``shaped`` flag)."""
        ...

    #: canonical families this model does not offer, and why
    not_offered: Mapping[str, str]
    #: the default cap on the number of effects
    max_effects: int

    def prepare(self, params: ResidualParams, say: Callable[[str], None]) -> Rows:
        """Check the record's length for ``params``, compute the nominal inputs."""
        ...

    def nominal(self) -> S:
        """The nominal model fitted on the fitting part."""
        ...

    def holdout_mse(self, state: S) -> float:
        """Mean square error of ``state`` on the held-out rows."""
        ...

    def holdout_rms(self, state: S) -> float:
        """Rms error of ``state`` on the held-out rows."""
        ...

    def search(self, name: str, state: S, fold: tuple[Fold, B] | None = None) -> Shape:
        """Shape of ``name`` from the residual of ``state`` on the fitting part (or of
        the model fitted without ``fold``, on its training rows)."""
        ...

    def extend(self, state: S, name: str, shape: Shape) -> Extension[S, C]:
        """``state`` plus the family with this shape, fitted on the fitting part."""
        ...

    def columns(self, name: str, shape: Shape) -> C:
        """The family's columns with this shape over the record."""
        ...

    def fold_fits(self, state: S, folds: list[Fold]) -> list[B]:
        """``state``'s structure fitted without each fold (and its errors there)."""
        ...

    def out_of_fold(
        self, state: S, folds: list[Fold], before: list[B], cols: C | list[C], sp: SelectionParams
    ) -> OutOfFold:
        """Out-of-fold squared errors before/after adding ``cols`` (one per fold when a
        list) to ``state`` over the fitting rows, and the candidate's support there."""
        ...

    def selected_params(self, state: S, index: int) -> dict[str, float]:
        """Reported parameters of the ``index``-th effect of ``state``."""
        ...

    def result(self, nominal: S, final: S, sel: Selection, say: Callable[[str], None]) -> Any:
        """The :class:`ResidualResult` of the selection."""
        ...


@dataclass(frozen=True)
class Selection:
    """What the greedy selection decided (the model turns it into a result)."""

    names: tuple[str, ...]
    candidates: tuple[CandidateScore, ...]
    indistinguishable: tuple[Ambiguity, ...]
    selection: SelectionParams
    rows: Rows


@dataclass(frozen=True, eq=False)
class _Trial:
    name: str
    ext: Extension[Any, Any]
    verdict: Verdict


_SCREENED = "screened out (shape of the whole fitting part; not re-searched)"


def _verdict(oof: OutOfFold, sp: SelectionParams) -> Verdict:
    return verdict(oof, sp.blocks, test=sp.test)


def _finite(shape: Mapping[str, float]) -> bool:
    return all(math.isfinite(v) for v in shape.values())


def _score(
    model: ResidualModel[Any, Any, Any],
    state: Any,
    folds: list[Fold],
    before: list[Any],
    name: str,
    sp: SelectionParams,
) -> tuple[CandidateScore, _Trial | None]:
    """Score family ``name`` on top of ``state``: its shape, its fit, its verdict."""
    rms0 = model.holdout_rms(state)
    shape = model.search(name, state)
    if not _finite(shape):
        return CandidateScore(name, shape, rms0, rms0, 0.0, 0.0, False, "no shape found"), None
    ext = model.extend(state, name, shape)
    mse1 = model.holdout_mse(ext.state)
    gain = 1.0 - mse1 / max(model.holdout_mse(state), 1e-300)
    rms1 = model.holdout_rms(ext.state)
    if not ext.added:
        note = "spanned by the current model (nothing new)"
        return CandidateScore(name, ext.params, rms0, rms1, gain, 0.0, False, note), None
    # screen with the shape of the whole fitting part (optimistic: the shape saw the
    # validation folds); a candidate that fails even this is not searched again
    ver = _verdict(model.out_of_fold(state, folds, before, ext.columns, sp), sp)
    note = ""
    if model.families[name].shaped:
        if (
            math.isfinite(ver.mean_effect)
            and ver.mean_effect >= 0.5 * sp.min_effect
            and (ver.p_value < 0.5)
        ):
            cols_k = []
            for fd, b_k in zip(folds, before):
                sh_k = model.search(name, state, (fd, b_k))
                cols_k.append(model.columns(name, sh_k if _finite(sh_k) else shape))
            ver = _verdict(model.out_of_fold(state, folds, before, cols_k, sp), sp)
        else:
            note = _SCREENED
    score = CandidateScore(
        name, ext.params, rms0, rms1, gain, ver.t_stat, False, note,
        cv_effect=ver.mean_effect, p_value=ver.p_value, folds_used=ver.folds_used,
        support_fraction=ver.support_fraction,
    )  # fmt: skip
    return score, _Trial(name, ext, ver)


def _choose(
    trials: list[_Trial], sp: SelectionParams
) -> tuple[list[_Trial], _Trial | None, list[_Trial]]:
    """Holm and the minimum size over a round's trials; the best accepted and its ties."""
    passes = holm([tr.verdict.p_value for tr in trials], sp.alpha)
    accepted = [
        tr for tr, ok in zip(trials, passes) if ok and tr.verdict.mean_effect >= sp.min_effect
    ]
    if not accepted:
        return accepted, None, []
    best = max(accepted, key=lambda tr: tr.verdict.total_reduction)
    same = [
        tr
        for tr in accepted
        if tr is best
        or (
            correlation(tr.ext.term, best.ext.term) >= sp.same_signal
            and tr.verdict.total_reduction >= (1.0 - sp.tie) * best.verdict.total_reduction
        )
    ]
    # the same signal on this record: the family with fewer columns is installed (it
    # carries the signal as well), all are named as indistinguishable here
    choice = min(same, key=lambda tr: (tr.ext.ncols, -tr.verdict.total_reduction))
    return accepted, choice, same


def analyse(
    model: ResidualModel[Any, Any, Any],
    params: ResidualParams = ResidualParams(),
    *,
    progress: Callable[[str], None] | None = None,
) -> ResidualResult:
    """Fit the nominal model, select effects greedily, report on the held-out end.

    Parameters
    ----------
    model : ResidualModel
        The record through a model: :class:`estimators.residual.rigid.RigidModel` or
        :class:`estimators.residual.two_inertia.TwoInertiaModel`.
    params : ResidualParams
        Settings.
    progress : callable, optional
        Called with a short message at each stage and candidate.

    Raises
    ------
    ParameterError
        A setting out of range or a record too short for the held-out split.
    """

    def say(msg: str) -> None:
        if progress is not None:
            progress(msg)

    offered = offered_families(params, model.families)
    cap = effect_cap(params, model.max_effects, model.families)
    rows = model.prepare(params, say)
    sp = params.selection
    folds = make_folds(rows.n, rows.split, sp.folds, rows.guard)
    nominal = state = model.nominal()
    selected: list[str] = []
    scores: dict[str, CandidateScore] = {}
    ambiguous: list[Ambiguity] = []
    while len(selected) < cap:
        say(f"cross-validation round {len(selected) + 1}")
        before = model.fold_fits(state, folds)
        trials: list[_Trial] = []
        for name in offered:
            if name in selected:
                continue
            say(f"candidate {name}")
            scores[name], trial = _score(model, state, folds, before, name, sp)
            if trial is not None:
                trials.append(trial)
        if not trials:
            break
        accepted, choice, same = _choose(trials, sp)
        for tr in trials:
            scores[tr.name] = replace(scores[tr.name], passed=tr in accepted)
        if choice is None:
            break
        if len(same) > 1:
            ambiguous.append(ambiguity([tr.name for tr in same], choice.name, sp.same_signal))
        selected.append(choice.name)
        state = choice.ext.state
        scores[choice.name] = replace(scores[choice.name], selected=True)
    # final joint parameters of the selected effects
    final = [
        replace(sc, params=model.selected_params(state, selected.index(sc.name)))
        if sc.selected
        else sc
        for sc in scores.values()
    ]
    sel = Selection(tuple(selected), tuple(final), tuple(ambiguous), sp, rows)
    res: ResidualResult = model.result(nominal, state, sel, say)
    return res


def apply(result: ResidualResult, model: Any) -> dict[str, float]:
    """Numbers of ``result``'s models (before/after) on a second record, nothing refitted.

    ``model`` is the second record through the same kind of model. Returns
    ``rms_before``, ``rms_after``, ``relerr_before``, ``relerr_after`` over every usable
    row of that record (none of it was fitted).

    Raises
    ------
    ParameterError
        The record is of another kind than the fitted one, or unusable.
    """
    if model.kind != result.kind:
        raise ParameterError("kind", f"a {result.kind} record like the fitted one", model.kind)
    out: dict[str, float] = model.evaluate(result)
    return out
