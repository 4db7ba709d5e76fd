"""Benchmark: a machining centre's pipeline at 500 Hz as a worker steps it (issue 32 item 3).

What one machining centre of a plant costs its worker, apart from the broker: a simulated
centre (plant machine 0's program ``O2001``, seed 0, one event in half of the parts) is
encoded as the drive blocks its edge device publishes (100 ms each, at 500 Hz:
:class:`server.pipeline.centre_feed.CentreFeed`; simulated before the clock starts), pushed
into a :class:`~server.pipeline.drive_feed.DriveFeed` (the checks of the broker's feed) and
read by a :class:`~server.pipeline.live_pipeline.LivePipeline` on an
:class:`~server.pipeline.mqtt_source.MqttSource`, 50 samples (100 ms) per step, as
``cutwatch worker`` does. The first 2 s warm up (the kernels loaded).

Figures: ``cpu_pct_of_core`` (the pipeline's CPU time, ``time.process_time``, over the
machine's seconds: % of one core per machine), ``wall_pct_of_core``, and per part
(:meth:`LivePipeline.costs`) ``part.<name>.pct`` with ``source.pct`` (reading the feed)
and ``pipeline.pct`` (the coordination), all in % of one core (wall time) per machine.
``cutwatch bench centre-pipeline --against REF`` measures it beside a commit's code.
"""

from __future__ import annotations

import statistics
import time

from server.experiments.benchmarks import Figures

#: the worker's block at 500 Hz (100 ms)
BLOCK = 50
#: samples of warm-up before the costs are counted (2 s)
WARM_BLOCKS = 20


def drive_blocks(seconds: float, seed: int = 0) -> tuple[bytes, list[bytes]]:
    """Machine 0's meta and ``seconds`` of its drive blocks (100 ms each, 500 Hz)."""
    from server.pipeline.centre_feed import CentreFeed, CentreFeedParams

    feed = CentreFeed(0, seed, CentreFeedParams(rate_hz=500.0, block_ms=100.0, event_rate=0.5))
    blocks = [feed.next_block(i) for i in range(round(seconds * 10))]
    return feed.meta, blocks


def pipeline_of(meta: bytes, blocks: list[bytes]) -> object:
    """A worker's pipeline over a feed holding ``blocks`` (nothing dropped)."""
    from server.pipeline.broker import parse_broker_url
    from server.pipeline.drive_feed import DriveFeed
    from server.pipeline.live_pipeline import LivePipeline
    from server.pipeline.mqtt_source import MqttSource

    feed = DriveFeed(parse_broker_url("mqtt://127.0.0.1:1"), "m000", max_samples=10**8)
    feed.push_meta(meta)
    for b in blocks:
        feed.push(b)
    return LivePipeline(source=MqttSource(feed))


def _run(meta: bytes, blocks: list[bytes]) -> dict[str, float]:
    from server.pipeline.live_pipeline import LivePipeline

    p = pipeline_of(meta, blocks)
    assert isinstance(p, LivePipeline)
    for _ in range(WARM_BLOCKS):
        p.step(BLOCK)
    p.reset_costs()
    c0 = time.process_time()
    w0 = time.perf_counter()
    for _ in range(len(blocks) - WARM_BLOCKS):
        p.step(BLOCK)
    cpu, wall = time.process_time() - c0, time.perf_counter() - w0
    c = p.costs()
    ms = c["machine_s"]
    out = {"cpu_pct_of_core": 100 * cpu / ms, "wall_pct_of_core": 100 * wall / ms}
    for name, v in c["parts"].items():
        if v["estimation_s"] > 0:
            out[f"part.{name}.pct"] = 100 * v["estimation_s"] / ms
    out["source.pct"] = 100 * c["source"]["simulation_s"] / ms
    out["pipeline.pct"] = 100 * c["pipeline"]["estimation_s"] / ms
    return out


def measure(*, repeats: int, quick: bool) -> Figures:
    """% of one core per machining centre at 500 Hz in 100 ms blocks, and by part."""
    seconds = 30.0 if quick else 120.0
    meta, blocks = drive_blocks(seconds)
    runs = [_run(meta, blocks) for _ in range(repeats)]
    res: Figures = {
        "config": f"machining centre O2001 seed 0 at 500 Hz, {seconds:g} s of drive blocks "
        f"through DriveFeed + MqttSource + LivePipeline, {BLOCK}-sample (100 ms) steps; "
        "% of one core per machine (medians)",
    }
    for k in runs[0]:
        res[k] = float(statistics.median(r.get(k, 0.0) for r in runs))
    return res
