"""Rolling accuracy of the force estimates: the running sums equal a direct computation."""

from __future__ import annotations

import math

import numpy as np
import pytest

from harness.accuracy import RollingAccuracy
from server.pipeline.live_pipeline import FORCE_ESTIMATES, LivePipeline

DT = 1e-3


def direct(errs: list[np.ndarray], ns: list[int], window: float) -> tuple[float, float]:
    """rms over the fewest newest whole blocks covering ``window``, and their span."""
    w = round(window / DT)
    held, parts = 0, []
    for e, n in zip(reversed(errs), reversed(ns), strict=True):
        parts.append(e)
        held += n
        if held >= w:
            break
    x = np.concatenate(parts)
    x = x[np.isfinite(x)]
    return (float(np.sqrt(np.mean(x * x))) if x.size else math.nan), held * DT


@pytest.mark.parametrize("seed", range(4))
def test_running_sums_equal_the_direct_rms_over_varying_blocks(seed: int) -> None:
    # blocks of 1..300 samples (a live feed's), through several turns of the ring; blocks
    # of 1..6 samples need more blocks than the ring's first 64 for 0.4 s: it grows
    rng = np.random.default_rng(seed)
    hi = 300 if seed % 2 else 6
    acc = RollingAccuracy(["a", "b"], DT, reference="truth", windows=(0.05, 0.4))
    ea: list[np.ndarray] = []
    eb: list[np.ndarray] = []
    eq: list[np.ndarray] = []
    floor: list[np.ndarray] = []
    ns: list[int] = []
    for i in range(600):
        n = int(rng.integers(1, hi)) if i % 50 else 0
        f = rng.normal(size=n)
        fq = f + 0.1 * rng.normal(size=n)
        a = f + rng.normal(scale=1 + i / 100, size=n)
        b = f + 0.5 * rng.normal(size=n)
        if i % 37 == 5 and n:
            b[0] = math.nan  # an observer's NaN is not counted
        acc.update({"a": a, "b": b}, f, fq)
        if n == 0:
            continue
        ea.append(a - f)
        eb.append(b - f)
        eq.append(a - fq)
        floor.append(fq - f)
        ns.append(n)
        if i % 7 == 0:
            s = acc.summary()
            assert acc._cap == 64 or hi == 6
            for j, w in enumerate(s["windows"]):  # type: ignore[arg-type]
                ra, span = direct(ea, ns, w)
                assert s["rms"]["a"][j] == pytest.approx(ra, rel=1e-9)  # type: ignore[index]
                assert s["rms"]["b"][j] == pytest.approx(direct(eb, ns, w)[0], rel=1e-9)  # type: ignore[index]
                assert s["rms_q"]["a"][j] == pytest.approx(direct(eq, ns, w)[0], rel=1e-9)  # type: ignore[index]
                assert s["floor"][j] == pytest.approx(direct(floor, ns, w)[0], rel=1e-9)  # type: ignore[index]
                assert s["span"][j] == pytest.approx(span)  # type: ignore[index]


def test_a_measured_force_is_the_reference_and_its_nan_samples_do_not_count() -> None:
    rng = np.random.default_rng(1)
    acc = RollingAccuracy(["a", "b"], DT, reference="measured_force", windows=(0.1,))
    f, a, b = rng.normal(size=100), rng.normal(size=100), rng.normal(size=100)
    f[:10] = math.nan  # the dynamometer not yet on
    acc.update({"a": a, "b": b}, measured=f)
    s = acc.summary()
    assert s["mode"] == "measured_force" and s["against"] == "measured_force"
    assert s["rms_q"] == {} and s["reason"] == ""
    want = float(np.sqrt(np.mean((a[10:] - f[10:]) ** 2)))
    assert s["rms"]["a"][0] == pytest.approx(want)  # type: ignore[index]
    assert all(math.isnan(v) for v in s["floor"])  # type: ignore[attr-defined]


def test_without_a_reference_nothing_is_scored_and_the_reason_is_said() -> None:
    acc = RollingAccuracy(["a", "b"], DT, reference="none", windows=(0.1,))
    acc.update({"a": np.zeros(100), "b": np.ones(100)})
    s = acc.summary()
    assert s["mode"] == "none" and s["against"] is None and "no reference" in s["reason"]  # type: ignore[operator]
    assert all(math.isnan(v) for r in s["rms"].values() for v in r)  # type: ignore[attr-defined]


def test_nothing_yet_is_nan_not_zero() -> None:
    s = RollingAccuracy(["a"], DT, reference="truth").summary()
    assert math.isnan(s["rms"]["a"][0]) and s["span"] == [0.0, 0.0]  # type: ignore[index]


def test_live_pipeline_scores_every_force_estimate_against_the_truth() -> None:
    p = LivePipeline("default")
    outs = [p.step(125) for _ in range(60)]  # 3 s
    acc = p.accuracy()
    assert acc["mode"] == "truth"
    assert (
        set(acc["rms"])
        == set(FORCE_ESTIMATES)
        == {  # type: ignore[arg-type]
            c.name for c in p.channels() if c.group == "force"
        }
        - {"f_true"}
    )
    last = {k: np.concatenate([o[k] for o in outs[-20:]]) for k in outs[0]}  # the last 1 s
    for k in FORCE_ESTIMATES:
        want = float(np.sqrt(np.mean((last[k] - last["f_true"]) ** 2)))
        assert acc["rms"][k][0] == pytest.approx(want, rel=1e-9)  # type: ignore[index]
    # the Q(s)-limited observers are closer to Q(s) F than to F (2.6-3.0 vs 0.5-1.2 N m)
    for k in ("f_fixed", "f_adaptive", "f_switching"):
        assert acc["rms_q"][k][0] < acc["rms"][k][0]  # type: ignore[index]
    assert acc["floor"][0] > 0  # type: ignore[index]
    assert p.snapshot()["accuracy"] == acc


def test_rounded_summary_for_the_stream() -> None:
    acc = RollingAccuracy(["a", "b"], DT, reference="truth", windows=(0.01, 1.0))
    f = np.linspace(-3.0, 3.0, 20)
    acc.update({"a": f + 0.0123456, "b": np.full(20, math.nan)}, f, f * 0.5)
    full, short = acc.summary(), acc.summary(digits=4)
    assert short["rms"]["a"] == [float(f"{v:.4g}") for v in full["rms"]["a"]]  # type: ignore[index]
    assert short["rms"]["a"][0] == 0.01235  # type: ignore[index]
    assert short["rms"]["b"] == [None, None]  # type: ignore[index]
    assert short["span"] == [0.02, 0.02] and short["floor"] == [  # type: ignore[index]
        float(f"{v:.4g}")
        for v in full["floor"]  # type: ignore[attr-defined]
    ]


def test_a_state_written_before_the_harness_moved_reads_as_now() -> None:
    # the harness's modules lived in server/pipeline/ (issue 34 moved them): a checkpoint
    # written then names server.pipeline.accuracy:RollingAccuracy (common.state_io.MOVED)
    from common.state_io import decode, encode

    acc = RollingAccuracy(["a"], DT, reference="truth", windows=(0.1,))
    acc.update({"a": np.array([1.0, 2.0])}, np.array([0.5, 1.5]), np.array([0.5, 1.5]))
    tree, arrays = encode(acc)
    assert tree["obj"] == "harness.accuracy:RollingAccuracy"
    old = {**tree, "obj": "server.pipeline.accuracy:RollingAccuracy"}
    back = decode(old, arrays)
    assert type(back) is RollingAccuracy
    assert back.summary() == acc.summary()
