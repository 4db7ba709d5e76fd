"""Any benchmark group measured on the code of a git commit side by side with this tree's.

``cutwatch bench GROUP --against REF``: the code of commit REF is unpacked from ``git
archive`` in a temporary folder; each tree runs the group's ``measure(repeats=1,
quick=...)`` in child processes of its own, in turn (before, after, before, after, ...),
``repeats`` times each, after one warm-up run each (numba compiles each tree's kernels
into that tree's cache, imports warm; none with ``quick``, a smoke check). Every number
the group reports is given as the median of each tree's runs, their spread (max / min)
and the ratio after / before: both trees measured under the same load, so the ratio is
what to read on a busy machine.

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
from dataclasses import dataclass
from pathlib import Path
from typing import TypedDict

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


#: one run's numeric figures by name
Figures = dict[str, float]
#: options passed on to a group's ``measure`` (the fleet group's: machines, workers, ...)
Options = dict[str, int | float | bool | None]


class Row(TypedDict):
    """One figure of both trees: medians, spreads (max / min) and after / before."""

    before: float
    before_spread: float
    after: float
    after_spread: float
    after_over_before: float


class BeforeAfter(TypedDict):
    """The comparison: the ref as given, its commit, runs per tree, the figures."""

    ref: str
    commit: str
    runs: int
    figures: dict[str, Row]


@dataclass(frozen=True)
class Run:
    """One child's result: its numeric figures and its other plain values as text."""

    figures: Figures
    labels: dict[str, str]


@dataclass(frozen=True)
class Comparison:
    """The group on both trees: this tree's medians and labels, and the comparison."""

    figures: Figures
    labels: dict[str, str]
    before_after: BeforeAfter


def split(res: dict[str, object]) -> Run:
    """A result's numeric figures (booleans aside) and its other plain values as text
    (nested values left out)."""
    figs: Figures = {}
    labels: dict[str, str] = {}
    for k, v in res.items():
        if isinstance(v, int | float) and not isinstance(v, bool):
            figs[k] = float(v)
        elif isinstance(v, str | bool):
            labels[k] = str(v)
    return Run(figs, labels)


def child(tree: Path, group: str, quick: bool, options: Options) -> Run:
    """One run of ``group``'s ``measure(repeats=1, quick=quick, **options)`` in a child
    process on ``tree``'s code (its stderr ours).

    Raises
    ------
    CutwatchError
        The child failed, or imported another tree's ``server``.
    """
    r = subprocess.run(
        [sys.executable, "-c", _CHILD, module_name(group), "1" if quick else "0",
         json.dumps(options)],
        cwd=tree, env={**os.environ, "PYTHONPATH": str(tree)},
        stdout=subprocess.PIPE, stderr=2, text=True, check=False,
    )  # fmt: skip
    if r.returncode != 0:
        raise CutwatchError(f"bench {group} on {tree} failed (exit {r.returncode}): see above")
    doc = json.loads(r.stdout.strip().splitlines()[-1])
    if not str(doc["server"]).startswith(str(tree)):
        raise CutwatchError(f"the child ran {doc['server']}, not the code of {tree}")
    return split(doc["result"])


def side_by_side(runs: dict[str, list[Figures]]) -> dict[str, Row]:
    """Per figure both trees report in every run: the medians of each tree's runs, their
    spreads (max / min) and the ratio of the medians after / before."""
    keys = [k for k in runs["after"][0] if all(k in r for rs in runs.values() for r in rs)]
    out: dict[str, Row] = {}
    for key in keys:
        med, spread = {}, {}
        for side in ("before", "after"):
            vals = [r[key] for r in runs[side]]
            med[side] = float(statistics.median(vals))
            lo, hi = min(vals), max(vals)
            spread[side] = hi / lo if lo > 0 else float("nan")
        out[key] = Row(
            before=med["before"],
            before_spread=spread["before"],
            after=med["after"],
            after_spread=spread["after"],
            after_over_before=med["after"] / med["before"] if med["before"] else float("nan"),
        )
    return out


def measure_against(
    group: str,
    ref: str,
    *,
    repeats: int,
    quick: bool,
    options: Options | None = None,
    progress: Callable[[str], None] | None = None,
    commit: str | None = None,
) -> Comparison:
    """``group`` on this tree and on commit ``ref``'s code, in turn (module doc);
    ``commit``: the commit ``ref`` was resolved to once for every group of a run (a branch
    that moves during a long run must not give the groups different "before" trees).

    Raises
    ------
    CutwatchError
        No such commit, the group missing in its code, or a run failed.
    """
    opts = options or {}
    say = progress or (lambda m: print(m, file=sys.stderr, flush=True))
    sha = commit or commit_of(ref)
    with tempfile.TemporaryDirectory(prefix="cutwatch-bench-before-") as d:
        trees = {"before": unpack(sha, Path(d)), "after": ROOT}
        path = Path("server/experiments/benchmarks") / f"{module_name(group)}.py"
        if not (trees["before"] / path).exists():
            raise CutwatchError(f"--against {ref!r}: no benchmark group {group!r} there ({path})")
        for side, t in trees.items() if not quick else ():
            # warm-up: kernels compiled and cached, imports warm (--quick: a smoke check,
            # none; the first runs then carry the compilation)
            say(f"  {group}: warm-up on {side} ({t})")
            child(t, group, True, opts)
        runs: dict[str, list[Run]] = {"before": [], "after": []}
        for i in range(repeats):
            say(f"  {group}: before/after run {i + 1}/{repeats}")
            for side, t in trees.items():
                runs[side].append(child(t, group, quick, opts))
    table = side_by_side({k: [r.figures for r in v] for k, v in runs.items()})
    return Comparison(
        figures={k: row["after"] for k, row in table.items()},
        labels=runs["after"][-1].labels,
        before_after=BeforeAfter(ref=ref, commit=sha, runs=repeats, figures=table),
    )
