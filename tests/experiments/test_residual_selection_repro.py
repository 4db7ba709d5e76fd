"""`cutwatch reproduce residual-selection --quick`: the Monte Carlo's contract and targets.

The quick run: 3 seeds of 10 s records, every family plus none, both kinds, the same
checks as the full run (whose measured table is in docs/residual-selection.md).
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
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


# the quick run's misses (3 seeds, so one case is 33 %; the full run's 20 seeds per case
# are in docs/residual-selection.md, where 113 of 114 checks hold):
# - seed 1's motion program (35 rad/s, 0.21 s dwell, the noisiest current of the three)
#   makes the simulator's regularised Coulomb law (tanh(w / 0.05 rad/s) against the
#   observer's sgn) read as a negative Stribeck term (F_s = -0.10 N m, v_s = 0.63 rad/s,
#   0.28 of the floor against the 0.25 minimum): a false positive on none and an extra
#   after offset / coulomb_asymmetry. Full run: 1 of 20 at 10 s and at 100 s (5 %, the
#   limit), 0 of 20 at 30 s;
# - seed 2's Stribeck is not found at 10 s (p 0.03 on a 7 s fitting part; full run 19 of
#   20 at 10 and 30 s, 20 of 20 at 100 s), and its in-band ratio over the quick seeds is
#   0.84 (full run 0.54 at 10 s, the one miss there; 0.47 at 30 s, 0.45 at 100 s).
KNOWN_MISSES = {
    "two_inertia.none.10s.false_positives <= 5 %",
    "two_inertia.offset.10s.spurious_extras <= 5 %",
    "two_inertia.coulomb_asymmetry.10s.spurious_extras <= 5 %",
    "two_inertia.stribeck.10s.right_first (or rightly indistinguishable) >= 95 %",
    "two_inertia.stribeck.10s.median_ratio <= 0.5",
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


def test_full_run_resumes_from_its_cache(tmp_path: Path) -> None:
    cache = tmp_path / "cases.jsonl"
    first = rs.Case("rigid", "none", 10.0, 1)
    second = rs.Case("rigid", "none", 10.0, 2)
    # a finished case (marked, so a recomputation would show) and a line cut short
    marked = {"kind": "rigid", "family": "none", "seconds": 10.0, "seed": 1,
              "selected": ["marker"], "groups": [], "installed": [], "ratio": 1.0,
              "elapsed": 0.0}  # fmt: skip
    cache.write_text(json.dumps(marked) + "\n" + '{"kind": "rigid", "fam')
    out = rs.run_cases([first, second], progress=False, workers=1, cache=cache)
    by_seed = {r["seed"]: r for r in out}
    assert by_seed[1]["selected"] == ["marker"]  # taken from the cache, not run again
    assert by_seed[2]["selected"] == [] and by_seed[2]["elapsed"] > 0.0
    kept = rs._load_cache(cache)
    assert set(kept) == {rs._key(first), rs._key(second)}
    assert len(rs.code_version()) == 16


def test_ratio_is_taken_where_the_family_acts() -> None:
    from types import SimpleNamespace

    both0, both1 = np.array([4.0, 4.0]), np.array([1.0, 1.0])
    force0, force1 = np.array([9.0, 9.0]), np.array([1.0, 1.0])
    res = SimpleNamespace(
        hold_sq_before=both0, hold_sq_after=both1, hold_sq_force_before=force0,
        hold_sq_force_after=force1, hold_speed=np.array([0.0, 100.0]),
    )  # fmt: skip
    # a load-side family: the force estimate only (its twist column is zero)
    sq0, sq1, where = rs._stage_sq(res, "coulomb_asymmetry", 1)
    assert rs._ratio(sq0, sq1) == pytest.approx(1.0 / 3.0) and where.all()
    # a shaft-side family: both channels
    sq0, sq1, _ = rs._stage_sq(res, "backlash", 1)
    assert rs._ratio(sq0, sq1) == pytest.approx(0.5)
    # Stribeck: only its speed band
    _, _, where = rs._stage_sq(res, "stribeck", 1)
    assert where.tolist() == [True, False]
