"""`cutwatch reproduce residual-selection --quick`: the Monte Carlo's contract and targets.

The quick run: 3 seeds of 10 s records, every family plus none, both kinds, the same
checks as the full run (whose measured table is in docs/residual-selection.md).
"""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from server.cli.main import main
from server.experiments.reproductions import residual_selection as rs


@pytest.fixture(scope="module")
def quick(tmp_path_factory: pytest.TempPathFactory) -> tuple[dict, Path]:
    plots = tmp_path_factory.mktemp("plots")
    rep = rs.run(quick=True, plot_dir=plots, progress=False)
    return rep.to_json(), plots


def test_rows_and_checks_follow_the_contract(quick: tuple[dict, Path]) -> None:
    rep, plots = quick
    assert rep["experiment"] == "residual-selection"
    names = {r["name"] for r in rep["rows"]}
    for kind, fams in (("rigid", rs.RIGID_FAMILIES), ("two_inertia", rs.STAGE_FAMILIES)):
        for fam in fams:
            base = f"{kind}.{fam}.10s"
            assert f"{base}.right_first" in names
            assert f"{base}.nothing_selected" in names
            if fam == "none":
                assert f"{base}.false_positives" in names
            else:
                assert f"{base}.spurious_extras" in names
                assert f"{base}.median_ratio" in names
    assert all(set(c) == {"name", "holds", "value", "limit"} for c in rep["checks"])
    assert (plots / "residual_selection.png").stat().st_size > 10_000


# targets the selection does not reach on the simulator (measured; the full run's numbers
# are in docs/residual-selection.md): Stribeck friction in the simulator acts as pulses
# where the vibrating load crosses zero speed within a sample; the family is found on
# 2 of 3 quick seeds (seed 2: nothing selected) and removes little of the error in its
# speed band (median ratio 0.98 over the 3 quick seeds). The simulator's direction asymmetry is the
# same signal as an offset while the load never sticks: the report names both as
# indistinguishable and installs the offset, whose held-out ratio is 0.60 (not 0.5).
KNOWN_MISSES = {
    "two_inertia.stribeck.10s.right_first (or rightly indistinguishable) >= 95 %",
    "two_inertia.stribeck.10s.median_ratio <= 0.5",
    "two_inertia.coulomb_asymmetry.10s.median_ratio <= 0.5",
}


def test_quick_run_meets_the_targets(quick: tuple[dict, Path]) -> None:
    rep, _ = quick
    failing = {c["name"]: c["value"] for c in rep["checks"] if not c["holds"]}
    assert set(failing) <= KNOWN_MISSES, failing
    # per kind: 6 families x 3 checks, plus the false positives on none
    assert len(rep["checks"]) == 2 * (6 * 3 + 1)


@pytest.mark.xfail(strict=True, reason="measured misses of the targets (see KNOWN_MISSES)")
def test_known_misses_reach_the_targets(quick: tuple[dict, Path]) -> None:
    rep, _ = quick
    assert all(c["holds"] for c in rep["checks"] if c["name"] in KNOWN_MISSES)


def test_listed_by_the_cli(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["reproduce", "--list"]) == 0
    assert "residual-selection" in capsys.readouterr().out


def test_score_counts_indistinguishable_only_when_named() -> None:
    base = {"family": "coulomb_asymmetry", "selected": ["offset"], "installed": ["offset"]}
    named = rs.score({**base, "groups": [["offset", "coulomb_asymmetry"]]})
    assert named["right_first"] == 0.0 and named["right_or_indistinguishable"] == 1.0
    assert named["spurious"] == 0.0
    unnamed = rs.score({**base, "groups": []})
    assert unnamed["right_or_indistinguishable"] == 0.0 and unnamed["spurious"] == 1.0
    none = rs.score({"family": "none", "selected": ["stribeck"], "groups": [], "installed": []})
    assert none["spurious"] == 1.0 and none["right_first"] == 0.0
    assert json.dumps(none)
