"""Sharding: a stable hash (the same shard in every process, whatever PYTHONHASHSEED),
spread evenly, the StatefulSet ordinal read from the host name, errors that name the
option."""

from __future__ import annotations

import subprocess
import sys

import pytest

from common.errors import ParameterError
from harness.shards import host_ordinal, owns, parse_shard, shard_of


def test_the_shard_does_not_depend_on_the_process() -> None:
    names = [f"m{k:03d}" for k in range(50)]
    here = [shard_of(m, 7) for m in names]
    code = f"from harness.shards import shard_of; print([shard_of(m, 7) for m in {names!r}])"
    for seed in ("1", "2"):  # Python's own hash() differs between these two processes
        out = subprocess.run(
            [sys.executable, "-c", code], capture_output=True, text=True, check=True,
            env={"PYTHONHASHSEED": seed, "PYTHONPATH": ":".join(sys.path)},
        ).stdout  # fmt: skip
        assert out.strip() == str(here)


def test_machines_spread_evenly_over_the_shards() -> None:
    n, shards = 4000, 4
    counts = [0] * shards
    for k in range(n):
        counts[shard_of(f"machine-{k}", shards)] += 1
    # binomial(4000, 1/4): sd 27; 5 sd either side
    assert all(abs(c - n / shards) < 5 * 27.4 for c in counts), counts


def test_every_machine_has_exactly_one_owner() -> None:
    for m in ("mill-1", "lathe-7", "m042"):
        assert sum(owns(m, (i, 3), None) for i in range(3)) == 1
    assert owns("a", None, frozenset({"a", "b"})) and not owns("c", None, frozenset({"a"}))


def test_the_shard_option() -> None:
    assert parse_shard("2/5") == (2, 5)
    assert parse_shard("host/4", hostname="cutwatch-worker-3") == (3, 4)
    assert host_ordinal("cutwatch-worker-12") == 12
    for bad in ("5/5", "-1/3", "a/3", "1", "1/0"):
        with pytest.raises(ParameterError, match="--shard"):
            parse_shard(bad)
    with pytest.raises(ParameterError, match="ordinal"):
        parse_shard("host/4", hostname="plant-box")
    with pytest.raises(ParameterError, match="--shard"):
        parse_shard("host/4", hostname="cutwatch-worker-4")
