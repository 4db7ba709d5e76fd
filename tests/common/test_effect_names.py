"""The effect names: the canonical list once (common/effects.py, docs/design.md), subsets
by meaning."""

from __future__ import annotations

from common.effects import CANONICAL_EFFECT_NAMES, REAL_DRIVE_EFFECT_NAMES
from estimators.observer_effects import COLUMNS, SIDES
from estimators.residual.rigid import FAMILIES, NOT_OFFERED
from estimators.residual.two_inertia import FAMILIES as FAMILIES_TWO_INERTIA
from estimators.residual.two_inertia import NOT_OFFERED_TWO_INERTIA
from machine.effects import EFFECT_NAMES

EFFECTS = set(CANONICAL_EFFECT_NAMES) - {"none"}


def test_canonical_names_are_unique() -> None:
    names = CANONICAL_EFFECT_NAMES + REAL_DRIVE_EFFECT_NAMES
    assert len(set(names)) == len(names)


def test_the_simulator_produces_only_canonical_effects() -> None:
    assert set(EFFECT_NAMES) <= EFFECTS, set(EFFECT_NAMES) - EFFECTS


def test_the_rigid_analysis_fits_or_declines_every_canonical_effect() -> None:
    assert not set(FAMILIES) & set(NOT_OFFERED)
    assert set(FAMILIES) | set(NOT_OFFERED) == EFFECTS | set(REAL_DRIVE_EFFECT_NAMES)


def test_the_two_inertia_analysis_fits_or_declines_every_canonical_effect() -> None:
    assert not set(FAMILIES_TWO_INERTIA) & set(NOT_OFFERED_TWO_INERTIA)
    assert set(FAMILIES_TWO_INERTIA) | set(NOT_OFFERED_TWO_INERTIA) == EFFECTS


def test_the_observer_effect_terms_cover_every_canonical_effect() -> None:
    assert set(SIDES) == EFFECTS
    assert set(COLUMNS) == EFFECTS
