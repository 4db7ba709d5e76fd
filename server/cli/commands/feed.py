"""Publish a measured log (or simulated machining centres) to an MQTT broker at real time,
as a machine's edge device would.

Each block of ``--block-ms`` of samples (at least one sample) goes to
``cutwatch/<machine>/drive`` in the binary wire format (docs/broker.md) with every column
the machine's description names and the CNC's identities (program, tool, G-code line,
override) in its header; the machine description goes first to
``cutwatch/<machine>/meta`` as a retained message. The machine is the sidecar's (or
``--meta``'s) ``axes`` (docs/machine-description.md), or one axis for an older sidecar.
This is the tool to test the ``mqtt`` source of ``cutwatch serve`` and to demonstrate it:
any log ``cutwatch replay``/``residual`` read (CSV + sidecar, or a ``.mat`` file with
``--map``) can be fed.

``--machine a,b,c`` publishes the same log for several machines from this one process
(one connection), as an edge gateway of a cell does: each machine's blocks are spread
over the block period (machine k of M is published k/M of a block later), not all at
once.

``--simulate`` publishes simulated machining centres instead of a log
(docs/machining-centre.md): ``--machines N`` of them (``NAME-1`` ... ``NAME-N``, machine
k with seed ``--seed`` + k, program O2001+k and its own events, ``--event-rate`` per
part), each its CNC's trace at ``--rate`` (500 Hz, 1, 2.5 or 5 kHz; ``--trace-mode``
a point sample per cycle or the cycle's mean), for ``--seconds`` or until interrupted.

Examples::

    cutwatch simulate --out run.csv --seconds 30
    cutwatch feed run.csv --broker mqtt://127.0.0.1:1883 --machine mill-1
    cutwatch feed run.csv --broker mqtt://127.0.0.1:1883 --machine mill-1,mill-2,mill-3
    cutwatch feed DATA_EMPS.mat --map tau_m=vir*gtau --map q_m=qm \\
        --meta '{"kind": "rigid", "units": {"effort": "N", "position": "m"}}' \\
        --broker mqtt://127.0.0.1:1883 --machine emps --speed 10
    cutwatch feed ../shared/data/cnc-mill/experiment_01.csv --meta cnc-mill.json \\
        --broker mqtt://127.0.0.1:1883 --machine mill-1 --speed 0   # docs/machines/
    cutwatch feed --simulate --broker mqtt://127.0.0.1:1883 --machine vmc --seconds 5
    cutwatch feed --simulate --broker mqtt://127.0.0.1:1883 --machine vmc --machines 3 \\
        --rate 1000 --trace-mode mean --seconds 5
"""

from __future__ import annotations

import argparse
import os
import time
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING

from server.cli.broker_options import add_broker_options, broker_config

if TYPE_CHECKING:
    from server.records.drive_wire import Segment
    from server.records.measured_log import MeasuredLog

HELP = (
    "publish a measured log, or simulated machining centres, to an MQTT broker at real time "
    "(the mqtt source's test feed)"
)


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "log", type=Path, nargs="?",
        help="measured log (.csv with .json sidecar, or .mat); not with --simulate",
    )  # fmt: skip
    p.add_argument("--broker", required=True, help="mqtt://host[:port] or mqtts://host[:port]")
    p.add_argument(
        "--machine",
        required=True,
        help="machine name (the topic's second level); a,b,c: several machines, one log; "
        "with --machines N: the names NAME-1 ... NAME-N",
    )
    p.add_argument(
        "--speed",
        type=float,
        default=1.0,
        help="log seconds per wall second; 0 publishes as fast as the broker takes them",
    )
    p.add_argument("--block-ms", type=float, default=50.0, help="samples per message [ms of log]")
    p.add_argument("--map", action="append", default=[], help="column map COL=EXPR (repeatable)")
    p.add_argument("--meta", help="sidecar keys as a JSON file or inline JSON object")
    sim = p.add_argument_group("a simulated machining centre (docs/machining-centre.md)")
    sim.add_argument("--simulate", action="store_true",
                     help="publish simulated machining centres' traces, not a log")  # fmt: skip
    sim.add_argument("--machines", type=int, default=1,
                     help="how many (each its own seed, program O2001+k and events)")  # fmt: skip
    sim.add_argument("--rate", type=float, default=500.0,
                     help="the trace's rate [Hz]: 500, 1000, 2500 or 5000")  # fmt: skip
    sim.add_argument("--trace-mode", choices=("sample", "mean"), default="sample",
                     help="a point sample per cycle or the cycle's mean")  # fmt: skip
    sim.add_argument("--seconds", type=float, default=0.0,
                     help="how long to simulate [s]; 0: until interrupted")  # fmt: skip
    sim.add_argument("--seed", type=int, default=0, help="machine k's seed is SEED + k")
    sim.add_argument("--event-rate", type=float, default=0.05,
                     help="chance per part of a breakage, collision or missing tool")  # fmt: skip
    add_broker_options(p)
    p.add_argument(
        "--float64", action="store_true", help="send efforts as float64 too (default float32)"
    )
    p.add_argument("--quiet", action="store_true", help="no progress bar")


def run(args: argparse.Namespace) -> int:
    from server.errors import CutwatchError

    if not (0 <= args.speed <= 1000):
        raise CutwatchError(f"--speed: expected a value in [0, 1000], got {args.speed}")
    if not (1 <= args.block_ms <= 1000):
        raise CutwatchError(f"--block-ms: expected a value in [1, 1000], got {args.block_ms}")
    if args.simulate == (args.log is not None):
        raise CutwatchError(
            "expected a log to feed or --simulate (one of the two), got "
            + ("both" if args.simulate else "neither")
        )
    machines = [m.strip() for m in args.machine.split(",") if m.strip()]
    if not machines:
        raise CutwatchError(f"--machine: expected a name or names a,b,c, got {args.machine!r}")
    from server.pipeline.broker import check_machine

    for m in machines:
        check_machine(m)  # a bad name is refused before anything is read or simulated
    sources = _simulated(args, machines) if args.simulate else _logged(args, machines)
    return _publish(args, sources)


class _Source:
    """What one machine publishes: its name, meta, sample time, samples per block, how
    many samples (None: until interrupted), and its blocks in order (``block(seq, a,
    wall)``: the block from sample ``a``)."""

    def __init__(
        self, name: str, meta: bytes, sample_time: float, per: int, n: int | None,
        block: Callable[[int, int, float], bytes],
    ) -> None:  # fmt: skip
        self.name, self.meta, self.sample_time = name, meta, sample_time
        self.per, self.n, self.block = per, n, block


def _logged(args: argparse.Namespace, machines: list[str]) -> list[_Source]:
    """The log, the same for every machine named."""
    from server.records.measured_log import load_log, load_meta

    log = load_log(args.log, meta=load_meta(args.meta), maps=args.map)
    plan = feed_plan(log, args.block_ms, args.float64)
    n, per = log.n, plan.per

    def block(seq: int, a: int, wall: float) -> bytes:
        return plan.block(seq, a, min(n, a + per), wall=wall)

    return [_Source(m, plan.meta, plan.sample_time, per, n, block) for m in machines]


def _simulated(args: argparse.Namespace, machines: list[str]) -> list[_Source]:
    """``--machines`` simulated machining centres (server.pipeline.centre_feed)."""
    from server.errors import CutwatchError
    from server.pipeline.centre_feed import CentreFeed, CentreFeedParams, plant

    if len(machines) != 1:
        raise CutwatchError(f"--machine: expected one name with --simulate, got {args.machine!r}")
    if not 1 <= args.machines <= 1000:
        raise CutwatchError(f"--machines: expected a count in [1, 1000], got {args.machines}")
    if not 0 <= args.seconds <= 1e7:
        raise CutwatchError(f"--seconds: expected a value in [0, 1e7], got {args.seconds}")
    params = CentreFeedParams(args.rate, args.trace_mode, args.block_ms, args.event_rate)
    names = (
        machines if args.machines == 1 else [f"{machines[0]}-{k + 1}" for k in range(args.machines)]
    )
    out = []
    for name, feed in zip(names, plant(args.machines, args.seed, params), strict=True):
        per = feed.per
        blocks = max(1, round(args.seconds / (per * feed.sample_time)))
        n = None if args.seconds == 0 else blocks * per

        def block(seq: int, a: int, wall: float, f: CentreFeed = feed) -> bytes:
            return f.next_block(seq, wall)

        out.append(_Source(name, feed.meta, feed.sample_time, per, n, block))
    return out


def _publish(args: argparse.Namespace, sources: list[_Source]) -> int:
    """Publish every source's meta (retained), then their blocks at ``--speed``, machine k
    of M k/M of a block later than the first, on one connection."""
    from tqdm import tqdm

    from server.pipeline.broker import connect_blocking, make_client, topic

    cfg = broker_config(args.broker, args)
    client = make_client(cfg, client_id=f"cutwatch-feed-{sources[0].name}-{os.getpid()}")
    connect_blocking(client, cfg)
    import paho.mqtt.client as mqtt

    assert isinstance(client, mqtt.Client)
    first = sources[0]
    ts, per, m, n = first.sample_time, first.per, len(sources), first.n
    drive = [topic(s.name, "drive") for s in sources]
    seq = 0
    try:
        for s in sources:
            client.publish(topic(s.name, "meta"), s.meta, qos=1, retain=True).wait_for_publish(10)
        start = time.monotonic()
        info = None
        with tqdm(
            total=n, desc=f"feed {args.machine[:40]}",
            unit="sample", unit_scale=True, disable=args.quiet,
        ) as bar:  # fmt: skip
            while n is None or seq * per < n:
                a = seq * per
                for k, s in enumerate(sources):
                    if args.speed > 0:  # published when its last sample is due (+ phase)
                        due = start + (a + per + k * per / m) * ts / args.speed
                        delay = due - time.monotonic()
                        if delay > 0:
                            time.sleep(delay)
                    info = client.publish(drive[k], s.block(seq, a, time.time()), qos=0)
                seq += 1
                bar.update(per if n is None else min(per, n - a))
        if info is not None:
            info.wait_for_publish(30)
    except KeyboardInterrupt:
        pass
    finally:
        client.loop_stop()
        client.disconnect()
    if not args.quiet:
        where = drive[0] if m == 1 else f"{m} machines' drive topics"
        sent = seq * per if n is None else min(seq * per, n)
        print(f"published {seq} blocks ({sent} samples) to {where} on {cfg.describe()}")
    return 0


class FeedPlan:
    """What ``cutwatch feed`` sends of a log: the meta, and each block's columns (every
    signal the machine names that the log has, with its unit) and identities."""

    def __init__(self, log: MeasuredLog, block_ms: float, float64: bool) -> None:
        from server.records.drive_wire import encode_meta

        self.log = log
        machine = log.machine
        # a described machine's declared rate; an older log's own interval (a replay of
        # the same log then sees the same times, to the last bit)
        self.sample_time = machine.sample_time if log.description else log.sample_time
        self.per = max(1, int(round(block_ms * 1e-3 / self.sample_time)))
        self.meta = encode_meta({**machine.to_dict(), "sample_time": self.sample_time})
        sig = [s for s in machine.signals() if s.owner != "identities" and s.source in log.columns]
        self.units = {s.source: s.unit for s in sig}
        self.names = list(self.units)
        self.dtypes = {k: "<f8" for k in self.names} if float64 else None
        ident = machine.identities
        self.ident = {r: log.columns[c] for r, c in ident.items() if c in log.columns}
        self.program = log.sidecar.get("program") if "program" not in self.ident else None

    def block(self, seq: int, a: int, b: int, wall: float) -> bytes:
        """The drive block of samples ``a:b`` (time from the log's first sample)."""
        from server.records.drive_wire import encode_drive

        cols = {k: self.log.columns[k][a:b] for k in self.names}
        t = self.log.columns["t"]
        return encode_drive(
            seq, float(t[a] - t[0]), self.sample_time, cols, self.units, self.dtypes,
            wall=wall, program=self._program(a), segments=self._segments(a, b),
        )  # fmt: skip

    def _program(self, a: int) -> str | None:
        """The program's name at sample ``a``: a column's number (``O1001`` -> its value
        as the CNC shows it), or the sidecar's ``program``."""
        import numpy as np

        if "program" not in self.ident:
            return self.program if isinstance(self.program, str) else None
        v = float(self.ident["program"][a])
        if not np.isfinite(v):
            return None
        return str(int(v)) if v == int(v) else f"{v:g}"

    def _segments(self, a: int, b: int) -> list[Segment]:
        """The identities of samples ``a:b`` as segments (an identity not known is tool 0
        / line 0, an override not known is not sent)."""
        from server.records.drive_wire import identity_segments

        tool, line, ovr = (self.ident.get(k) for k in ("tool", "line", "override"))
        return identity_segments(
            None if tool is None else tool[a:b],
            None if line is None else line[a:b],
            None if ovr is None else ovr[a:b],
        )


def feed_plan(log: MeasuredLog, block_ms: float, float64: bool) -> FeedPlan:
    """The plan of a feed of ``log`` (see :class:`FeedPlan`).

    Raises
    ------
    LogFormatError
        The log does not describe a machine (e.g. a rate outside 10 Hz-10 kHz).
    """
    return FeedPlan(log, block_ms, float64)
