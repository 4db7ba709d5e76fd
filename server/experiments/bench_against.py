"""Any benchmark group measured on the code of a git commit side by side with this tree's.

``cutwatch bench GROUP --against REF``: the code of commit REF is unpacked from ``git
archive`` in a temporary folder; each tree runs the group's ``measure(repeats=1,
quick=...)`` in child processes of its own, in turn (before, after, before, after, ...),
``repeats`` times each, after one warm-up run each (numba compiles each tree's kernels
into that tree's cache, imports warm). Every number the group reports is given as the
median of each tree's runs, their spread (max / min) and the ratio after / before: both
trees measured under the same load, so the ratio is what to read on a busy machine.

A child runs with the tree as its working directory and its only ``PYTHONPATH`` entry,
and says which ``server`` package it imported (refused if not the tree's); its output goes
to stderr, its one JSON line (the last on its stdout) is read. The group must exist in
both trees under the same module name (``bench_<group>.py``).
"""

from __future__ import annotations

import json
import os
import statistics
import subprocess
import sys
import tempfile
from collections.abc import Callable
from pathlib import Path
from typing import Any

from server.errors import CutwatchError

#: the tree this module runs from (its git repository)
ROOT = Path(__file__).resolve().parents[2]

#: what a child process runs: the benchmark module's ``measure`` (a surface every tree's
#: groups have), the group's own prints sent to stderr, one JSON line on stdout
_CHILD = """
import contextlib, importlib, json, sys
import server
module, quick, kwargs = sys.argv[1], sys.argv[2] == "1", json.loads(sys.argv[3])
mod = importlib.import_module("server.experiments.benchmarks." + module)
with contextlib.redirect_stdout(sys.stderr):
    res = mod.measure(repeats=1, quick=quick, **kwargs)
print(json.dumps({"result": res, "server": server.__file__}, default=str))
"""


def commit_of(ref: str, root: Path = ROOT) -> str:
    """The commit ``ref`` names in ``root``'s repository.

    Raises
    ------
    CutwatchError
        Not a git checkout, or no such commit (git's message).
    """
    r = subprocess.run(
        ["git", "-C", str(root), "rev-parse", "--verify", "--quiet", f"{ref}^{{commit}}"],
        capture_output=True, text=True, check=False,
    )  # fmt: skip
    if r.returncode != 0:
        why = r.stderr.strip() or "no such commit in " + str(root)
        raise CutwatchError(f"--against {ref!r}: git archive failed: {why}")
    return r.stdout.strip()


def unpack(ref: str, into: Path, root: Path = ROOT) -> Path:
    """The code of git commit ``ref`` unpacked in ``into``.

    Raises
    ------
    CutwatchError
        Not a git checkout, or no such commit (git's message).
    """
    arch = subprocess.run(
        ["git", "-C", str(root), "archive", "--format=tar", ref], capture_output=True
    )
    if arch.returncode != 0:
        msg = arch.stderr.decode(errors="replace").strip()
        raise CutwatchError(f"--against {ref!r}: git archive failed: {msg}")
    subprocess.run(["tar", "-x", "-C", str(into)], input=arch.stdout, check=True)
    return into


def module_name(group: str) -> str:
    """The benchmark module of a group: ``tool-wear`` -> ``bench_tool_wear``."""
    return "bench_" + group.replace("-", "_")


def child(tree: Path, group: str, quick: bool, kwargs: dict[str, Any]) -> dict[str, Any]:
    """One run of ``group``'s ``measure(repeats=1, quick=quick, **kwargs)`` in a child
    process on ``tree``'s code (its stderr ours); the group's result.

    Raises
    ------
    CutwatchError
        The child failed, or imported another tree's ``server``.
    """
    r = subprocess.run(
        [sys.executable, "-c", _CHILD, module_name(group), "1" if quick else "0",
         json.dumps(kwargs)],
        cwd=tree, env={**os.environ, "PYTHONPATH": str(tree)},
        stdout=subprocess.PIPE, stderr=2, text=True, check=False,
    )  # fmt: skip
    if r.returncode != 0:
        raise CutwatchError(f"bench {group} on {tree} failed (exit {r.returncode}): see above")
    doc: dict[str, Any] = json.loads(r.stdout.strip().splitlines()[-1])
    if not str(doc["server"]).startswith(str(tree)):
        raise CutwatchError(f"the child ran {doc['server']}, not the code of {tree}")
    res: dict[str, Any] = doc["result"]
    return res


def numbers(res: dict[str, Any]) -> dict[str, float]:
    """The numeric figures of one result (booleans, strings and nested values left out)."""
    return {
        k: float(v)
        for k, v in res.items()
        if isinstance(v, int | float) and not isinstance(v, bool)
    }


def side_by_side(runs: dict[str, list[dict[str, Any]]]) -> dict[str, dict[str, float]]:
    """Per figure both trees report: the medians of each tree's runs, their spreads
    (max / min) and the ratio of the medians after / before."""
    nums = {k: [numbers(r) for r in v] for k, v in runs.items()}
    keys = [k for k in nums["after"][0] if all(k in r for rs in nums.values() for r in rs)]
    out: dict[str, dict[str, float]] = {}
    for key in keys:
        row: dict[str, float] = {}
        for side in ("before", "after"):
            vals = [r[key] for r in nums[side]]
            row[side] = float(statistics.median(vals))
            lo, hi = min(vals), max(vals)
            row[f"{side}_spread"] = hi / lo if lo > 0 else float("nan")
        row["after_over_before"] = row["after"] / row["before"] if row["before"] else float("nan")
        out[key] = row
    return out


def measure_against(
    group: str,
    ref: str,
    *,
    repeats: int,
    quick: bool,
    kwargs: dict[str, Any] | None = None,
    progress: Callable[[str], None] | None = None,
) -> dict[str, Any]:
    """``group`` on this tree and on commit ``ref``'s code, in turn (module doc).

    The result is the group's own, from this tree's runs (numbers: medians; the rest from
    the last run), plus ``before_after``: the ref, its commit, the runs per tree, and per
    figure the medians, spreads and ratio (:func:`side_by_side`).

    Raises
    ------
    CutwatchError
        No such commit, the group missing in its code, or a run failed.
    """
    kw = kwargs or {}
    say = progress or (lambda m: print(m, file=sys.stderr, flush=True))
    sha = commit_of(ref)
    with tempfile.TemporaryDirectory(prefix="cutwatch-bench-before-") as d:
        trees = {"before": unpack(sha, Path(d)), "after": ROOT}
        path = Path("server/experiments/benchmarks") / f"{module_name(group)}.py"
        if not (trees["before"] / path).exists():
            raise CutwatchError(f"--against {ref!r}: no benchmark group {group!r} there ({path})")
        for side, t in trees.items():  # warm-up: kernels compiled and cached, imports warm
            say(f"  {group}: warm-up on {side} ({t})")
            child(t, group, True, kw)
        runs: dict[str, list[dict[str, Any]]] = {"before": [], "after": []}
        for i in range(repeats):
            say(f"  {group}: before/after run {i + 1}/{repeats}")
            for side, t in trees.items():
                runs[side].append(child(t, group, quick, kw))
    after = runs["after"]
    out: dict[str, Any] = {k: v for k, v in after[-1].items() if k not in numbers(after[-1])}
    table = side_by_side(runs)
    out.update({k: row["after"] for k, row in table.items()})
    out["before_after"] = {"ref": ref, "commit": sha, "runs": repeats, "figures": table}
    return out
