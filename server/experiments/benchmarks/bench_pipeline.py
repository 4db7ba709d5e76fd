"""Benchmark: the live service's whole pipeline, offline (no server, no clients).

``server.pipeline.live_pipeline.LivePipeline`` on the default scenario steps the two-inertia X stage
with its three force observers and both RLS, the harmonic observer (DFO), the tool wear
model and its life monitor, the milling machine with eccentricity on its X/Y drives
with the ESC, and the part program on seed 003's machine with the drives' force
observers and the process monitor (issue 21): every estimator the service runs.
Simulated seconds per wall second (medians) at the live block (125 samples = 50 ms) and
at offline blocks (2500 samples = 1 s), after 2 s of warm-up (compiled kernels loaded,
observers settled).

What watching a machine costs, apart from simulating one (issue 26): the pipeline counts
the wall time of every part's estimation apart from its simulation
(:meth:`LivePipeline.costs`: the simulated machine's script, a simulating part's own
machine, the simulator's stage), per machine-second at the live block: ``cost.*_ms``
(medians over the runs; ``part.<name>.estimation_ms`` and ``.simulation_ms`` per part,
``source.simulation_ms`` the stage's simulator, ``pipeline.estimation_ms`` the
coordination: the block, the accuracy).

``against=REF`` (``cutwatch bench pipeline --against main``): the same pipeline on the
code of git commit REF, measured side by side with this tree's in one run: each tree in
its own child processes (``git archive REF`` unpacked in a temporary folder), run in
turn, ``repeats`` each, after one warm-up run each (numba compiles the other tree's
kernels into its own cache); ``before_after.*`` the medians and spreads (wall ms per
machine-second, live block) and the ratio. A child's output goes to stderr, its one JSON
line is read.
"""

from __future__ import annotations

import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

from server.errors import CutwatchError
from server.pipeline.live_pipeline import LivePipeline

#: the tree this module runs from (its git repository)
ROOT = Path(__file__).resolve().parents[3]
#: what a child process runs: the public surface both trees have (LivePipeline, step)
_CHILD = """
import json, sys, time
import server
from server.pipeline.live_pipeline import LivePipeline
seconds = float(sys.argv[1])
p = LivePipeline("default")
dt = 125 * p.sample_time
for _ in range(round(2.0 / dt)):
    p.step(125)
n = max(1, round(seconds / dt))
t0 = time.perf_counter()
for _ in range(n):
    p.step(125)
wall = time.perf_counter() - t0
print(json.dumps({"ms_per_machine_s": 1e3 * wall / (n * dt), "server": server.__file__}))
"""


def _rate(block: int, seconds: float, repeats: int) -> tuple[float, list[dict[str, Any]]]:
    rates, costs = [], []
    for _ in range(repeats):
        p = LivePipeline("default")
        warm = max(1, round(2.0 / (block * p.sample_time)))
        for _ in range(warm):
            p.step(block)
        p.reset_costs()
        n = max(1, round(seconds / (block * p.sample_time)))
        t0 = time.perf_counter()
        for _ in range(n):
            p.step(block)
        rates.append(n * block * p.sample_time / (time.perf_counter() - t0))
        costs.append(p.costs())
    return float(statistics.median(rates)), costs


def _per_machine_second(costs: list[dict[str, Any]]) -> dict[str, float]:
    """Median over the runs of each cost, in ms per machine-second."""
    rows: dict[str, list[float]] = {}

    def add(key: str, seconds: float, machine_s: float) -> None:
        rows.setdefault(key, []).append(1e3 * seconds / machine_s)

    for c in costs:
        ms = c["machine_s"]
        est = c["pipeline"]["estimation_s"]
        sim = c["source"]["simulation_s"]
        for name, v in c["parts"].items():
            add(f"part.{name}.estimation_ms", v["estimation_s"], ms)
            add(f"part.{name}.simulation_ms", v["simulation_s"], ms)
            est += v["estimation_s"]
            sim += v["simulation_s"]
        add("source.simulation_ms", c["source"]["simulation_s"], ms)
        add("pipeline.estimation_ms", c["pipeline"]["estimation_s"], ms)
        add("cost.estimation_ms", est, ms)
        add("cost.simulation_ms", sim, ms)
        add("cost.wall_ms", c["wall_s"], ms)
    return {k: float(statistics.median(v)) for k, v in rows.items()}


def _commit(ref: str) -> str:
    """The commit ``ref`` names.

    Raises
    ------
    CutwatchError
        Not a git checkout, or no such commit (git's message).
    """
    r = subprocess.run(
        ["git", "-C", str(ROOT), "rev-parse", "--verify", "--quiet", f"{ref}^{{commit}}"],
        capture_output=True, text=True, check=False,
    )  # fmt: skip
    if r.returncode != 0:
        why = r.stderr.strip() or "no such commit in " + str(ROOT)
        raise CutwatchError(f"--against {ref!r}: git archive failed: {why}")
    return r.stdout.strip()


def _tree(ref: str, into: Path) -> Path:
    """The code of git commit ``ref`` unpacked in ``into``.

    Raises
    ------
    CutwatchError
        Not a git checkout, or no such commit (git's message).
    """
    arch = subprocess.run(
        ["git", "-C", str(ROOT), "archive", "--format=tar", ref], capture_output=True
    )
    if arch.returncode != 0:
        msg = arch.stderr.decode(errors="replace").strip()
        raise CutwatchError(f"--against {ref!r}: git archive failed: {msg}")
    subprocess.run(["tar", "-x", "-C", str(into)], input=arch.stdout, check=True)
    return into


def _child(tree: Path, seconds: float) -> dict[str, Any]:
    """One run of the pipeline in a child process on ``tree``'s code (its stderr ours)."""
    r = subprocess.run(
        [sys.executable, "-c", _CHILD, str(seconds)],
        cwd=tree, env={**os.environ, "PYTHONPATH": str(tree)},
        stdout=subprocess.PIPE, stderr=2, text=True, check=False,
    )  # fmt: skip
    if r.returncode != 0:
        raise CutwatchError(f"the pipeline on {tree} failed (exit {r.returncode}): see above")
    doc: dict[str, Any] = json.loads(r.stdout.strip().splitlines()[-1])
    if not str(doc["server"]).startswith(str(tree)):
        raise CutwatchError(f"the child ran {doc['server']}, not the code of {tree}")
    return doc


def _before_after(ref: str, seconds: float, repeats: int) -> dict[str, object]:
    """This tree's pipeline and ``ref``'s, in turn, ``repeats`` runs each (module doc)."""
    with tempfile.TemporaryDirectory(prefix="cutwatch-bench-before-") as d:
        trees = {"before": _tree(ref, Path(d)), "after": ROOT}
        for t in trees.values():  # warm-up: the kernels compiled and cached, imports warm
            _child(t, 0.5)
        runs: dict[str, list[float]] = {"before": [], "after": []}
        for i in range(repeats):
            print(f"  before/after run {i + 1}/{repeats}", file=sys.stderr, flush=True)
            for k, t in trees.items():
                runs[k].append(float(_child(t, seconds)["ms_per_machine_s"]))
    out: dict[str, object] = {"before_after.before": ref}
    for k, v in runs.items():
        out[f"before_after.{k}_ms"] = float(statistics.median(v))
        out[f"before_after.{k}_spread"] = max(v) / min(v)
    b, a = out["before_after.before_ms"], out["before_after.after_ms"]
    assert isinstance(a, float) and isinstance(b, float)
    out["before_after.after_over_before"] = a / b
    out["before_after.runs"] = {k: v for k, v in runs.items()}
    return out


def measure(*, repeats: int, quick: bool, against: str | None = None) -> dict[str, object]:
    """Realtime factors of the whole live pipeline at two block sizes, its cost per
    machine-second by part (estimation apart from simulation), and with ``against`` the
    same beside the code of that git commit."""
    seconds = 5.0 if quick else 30.0
    if against:
        _commit(against)  # a bad commit refused before anything is measured
    live, costs = _rate(125, seconds, repeats)
    res: dict[str, object] = {
        "config": f"LivePipeline('default'), every estimator, {seconds:g} s simulated per run; "
        "costs in ms of wall time per machine-second at the live block (125 samples)",
        "live_block_125.realtime_factor": live,
        "offline_block_2500.realtime_factor": _rate(2500, seconds, repeats)[0],
        **_per_machine_second(costs),
    }
    if against:
        res.update(_before_after(against, seconds, repeats))
    res["realtime_factor"] = res["offline_block_2500.realtime_factor"]
    return res
