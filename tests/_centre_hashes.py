"""A machining centre's pipeline at 500 Hz over a broker feed, hashed channel by channel
(issue 32 item 3: the plant's cost cut without changing what is streamed).

The worker's pipeline (:mod:`server.experiments.benchmarks.bench_centre_pipeline`: plant
machine 0's drive blocks through a ``DriveFeed`` and an ``MqttSource``) is stepped over
:data:`SECONDS` of the centre, in the worker's 100 ms steps with a catch-up step of
400 ms every tenth step (a worker behind takes a longer block), and every channel, the
events raised and the monitor's status at the end are hashed (:func:`tests._hashes.digest`).
``tests/pipeline/centre_hashes.json`` holds the hashes the code before the cost cuts gave
(written by ``python tests/_centre_hashes.py --write`` on the commit that added them,
before the cuts); ``tests/pipeline/test_centre_hashes.py`` compares.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path
from typing import Any

import numpy as np
from _hashes import _event, _json_digest, digest

from server.experiments.benchmarks.bench_centre_pipeline import drive_blocks, pipeline_of
from server.pipeline.live_pipeline import LivePipeline

HASHES = Path(__file__).parent / "pipeline" / "centre_hashes.json"
#: past the monitors' teach-in (five parts, ~160 s), so that events are raised
SECONDS = 220.0


def centre_hashes() -> dict[str, Any]:
    """The hashes of the run (module docstring)."""
    meta, blocks = drive_blocks(SECONDS)
    p = pipeline_of(meta, blocks)
    assert isinstance(p, LivePipeline)
    outs: list[dict[str, np.ndarray]] = []
    events: list[dict[str, Any]] = []
    k = 0
    while True:
        out = p.step(200 if k % 10 == 9 else 50)
        k += 1
        if out["t"].size == 0:
            break
        outs.append(out)
        events += [_event(e) for e in p.take_events()]
    names = sorted({n for o in outs for n in o})
    chans = {n: digest(np.concatenate([o[n] for o in outs])) for n in names}
    return {
        "samples": int(sum(o["t"].size for o in outs)),
        "channels": chans,
        "events": {"count": len(events), "hash": _json_digest(events)},
        "status": _json_digest([p.monitor_status()]),
    }


def main(argv: list[str]) -> int:
    got = centre_hashes()
    if "--write" in argv:
        HASHES.write_text(json.dumps(got, indent=1, sort_keys=True) + "\n")
    print(json.dumps({k: v for k, v in got.items() if k != "channels"}))
    print(len(got["channels"]), "channels")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
