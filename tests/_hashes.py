"""Fixed-seed runs of the live pipeline, hashed channel by channel (issue 26).

The live path was refactored into parts (issue 26); what it streams must not change. Each
run below steps a :class:`~server.pipeline.live_pipeline.LivePipeline` through the same
script of knob changes, injections and a checkpoint round trip, and hashes every channel's
samples (sha256 of the float64 bytes, NaN made canonical), the events raised (id left
out: a random uuid) and the tools changed. ``tests/pipeline/channel_hashes.json`` holds
the hashes the code before the refactor gave (written by ``python tests/_hashes.py
--write`` on that code, commit 67b7f98); ``tests/pipeline/test_channel_hashes.py`` compares
and names each difference with its reason.

Only the pipeline's public surface is used (``LivePipeline(scenario, seed=)``,
``step``, ``set_knob``, ``inject``, ``take_events``, ``take_tool_changes``, ``state``,
``restore``, ``from_log``), the same before and after.
"""

from __future__ import annotations

import hashlib
import json
import sys
import tempfile
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from machine.stage import SEED000_FORCE, StageConfig
from machine.stage_params import preset
from server.pipeline.checkpoint import load_checkpoint, save_checkpoint
from server.pipeline.live_pipeline import LivePipeline
from server.pipeline.sources import SimulatorSource
from server.records.measured_log import write_log

#: where the hashes of the code before the refactor are kept
HASHES = Path(__file__).parent / "pipeline" / "channel_hashes.json"
BLOCK = 125  # 50 ms at 2.5 kHz, the service's block
#: one canonical NaN (np.full(n, nan) and a NaN out of arithmetic may differ in sign bit)
_NAN = np.float64("nan")


@dataclass(frozen=True)
class Run:
    """One fixed-seed run: scenario, seed, seconds, and what happens at which block."""

    scenario: str
    seed: int
    seconds: float
    #: block index -> action on the pipeline (knob changes, injections...)
    script: dict[int, Callable[[LivePipeline], None]] = field(default_factory=dict)
    #: block index at which the state goes through a checkpoint file into a fresh pipeline
    checkpoint_at: int | None = None
    #: a replayed log instead of a scenario (the path is made by :func:`_replay_log`)
    replay: bool = False


def _knobs(**kv: object) -> Callable[[LivePipeline], None]:
    def act(p: LivePipeline) -> None:
        for k, v in kv.items():
            p.set_knob(k, v)

    return act


def _inject(kind: str) -> Callable[[LivePipeline], None]:
    def act(p: LivePipeline) -> None:
        p.inject(kind)

    return act


#: the runs, by name (20 blocks per second)
RUNS: dict[str, Run] = {
    # the default scenario, busy: a short teach-in, a fast wear (tool changes, wear
    # alarms), the tuner switched, a breakage and a collision injected, a checkpoint
    "default-0": Run(
        "default",
        0,
        60.0,
        {
            0: _knobs(teach_parts=1, wear_rate=5.0),
            300: _knobs(tuner="fast", ecc_force="adaptive"),
            500: _inject("breakage"),
            700: _knobs(effect_coulomb_asymmetry=True, current_noise=0.01),
            900: _inject("collision"),
        },
        checkpoint_at=600,
    ),
    "default-1": Run("default", 1, 30.0),
    "seed000-weight-0": Run("seed000-weight", 0, 20.0, {100: _knobs(weight_on=True)}),
    "seed001-spindle-0": Run("seed001-spindle", 0, 20.0),
    "replay-0": Run("replay", 0, 6.0, replay=True),
}


def digest(a: np.ndarray) -> str:
    """sha256 of a float64 array's bytes, NaN made canonical (first 16 hex digits)."""
    x = np.ascontiguousarray(a, dtype=np.float64).copy()
    x[np.isnan(x)] = _NAN
    return hashlib.sha256(x.tobytes()).hexdigest()[:16]


def _json_digest(items: list[Any]) -> str:
    text = json.dumps(items, sort_keys=True, default=str, allow_nan=True)
    return hashlib.sha256(text.encode()).hexdigest()[:16]


def _replay_log(path: Path) -> Path:
    """8 s of seed 000's stage (seed 0) as a measured log, with its reference force."""
    cfg = StageConfig(params=preset("seed000"), force=SEED000_FORCE)
    m = SimulatorSource(cfg, seed=0).step(20000).meas
    cols = {k: getattr(m, k) for k in ("t", "tau_m", "i_m", "q_m", "q_l", "f_ext")}
    side = {
        "sample_time": cfg.sample_time,
        "units": {"effort": "N m", "position": "rad", "current": "A"},
        "kind": "two_inertia",
        "nominal": cfg.params.as_dict(),
        "encoder_resolution": cfg.encoder_resolution,
    }
    write_log(path, cols, side)
    return path


def _event(ev: Any) -> dict[str, Any]:
    d = dict(ev.as_dict())
    d.pop("id", None)
    return d


def run_hashes(run: Run, tmp: Path) -> dict[str, Any]:
    """The hashes of one run: every channel, the events and the tool changes."""
    if run.replay:
        p = LivePipeline.from_log(_replay_log(tmp / "replay.csv"), seed=run.seed)
    else:
        p = LivePipeline(run.scenario, seed=run.seed)
    blocks = round(run.seconds / (BLOCK * p.sample_time))
    outs: list[dict[str, np.ndarray]] = []
    events: list[dict[str, Any]] = []
    tools: list[dict[str, Any]] = []
    for k in range(blocks):
        act = run.script.get(k)
        if act is not None:
            act(p)
        if run.checkpoint_at == k:
            path = tmp / "state.npz"
            save_checkpoint(path, p.state())
            fresh = LivePipeline(run.scenario, seed=run.seed)
            fresh.restore(load_checkpoint(path))
            p = fresh
        outs.append(p.step(BLOCK))
        events += [_event(e) for e in p.take_events()]
        tools += p.take_tool_changes()
    names = list(outs[0])
    chans = {k: digest(np.concatenate([o[k] for o in outs])) for k in names}
    return {
        "samples": int(sum(o["t"].size for o in outs)),
        "channels": chans,
        "events": {"count": len(events), "hash": _json_digest(events)},
        "tool_changes": {"count": len(tools), "hash": _json_digest(tools)},
    }


def all_hashes(names: list[str] | None = None) -> dict[str, Any]:
    """The hashes of the runs named (default: all)."""
    with tempfile.TemporaryDirectory() as d:
        return {n: run_hashes(RUNS[n], Path(d)) for n in names or list(RUNS)}


def compare(old: dict[str, Any], new: dict[str, Any]) -> list[str]:
    """Every difference between two runs' hashes, one line each (empty: identical)."""
    out = []
    for key in ("samples", "events", "tool_changes"):
        if old[key] != new[key]:
            out.append(f"{key}: {old[key]} -> {new[key]}")
    oc, nc = old["channels"], new["channels"]
    for name in sorted(set(oc) | set(nc)):
        if name not in nc:
            out.append(f"channel {name}: gone")
        elif name not in oc:
            out.append(f"channel {name}: new")
        elif oc[name] != nc[name]:
            out.append(f"channel {name}: {oc[name]} -> {nc[name]}")
    return out


def main(argv: list[str]) -> int:
    """``--write``: store the hashes of this tree's code; else compare with the stored."""
    got = all_hashes()
    if "--write" in argv:
        HASHES.write_text(json.dumps(got, indent=1, sort_keys=True) + "\n")
        print(f"wrote {HASHES}")
        return 0
    want = json.loads(HASHES.read_text())
    bad = 0
    for name in RUNS:
        diff = compare(want[name], got[name])
        bad += len(diff)
        print(f"{name}: {'identical' if not diff else ''}")
        for line in diff:
            print(f"  {line}")
    return 1 if bad else 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
