"""Publish a measured log to an MQTT broker at real time, as a machine's edge device would.

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

Examples::

    cutwatch simulate --out run.csv --seconds 30
    cutwatch feed run.csv --broker mqtt://127.0.0.1:1883 --machine mill-1
    cutwatch feed run.csv --broker mqtt://127.0.0.1:1883 --machine mill-1,mill-2,mill-3
    cutwatch feed DATA_EMPS.mat --map tau_m=vir*gtau --map q_m=qm \\
        --meta '{"kind": "rigid", "units": {"effort": "N", "position": "m"}}' \\
        --broker mqtt://127.0.0.1:1883 --machine emps --speed 10
    cutwatch feed ../shared/data/cnc-mill/experiment_01.csv --meta cnc-mill.json \\
        --broker mqtt://127.0.0.1:1883 --machine mill-1 --speed 0   # docs/machines/
"""

from __future__ import annotations

import argparse
import os
import time
from pathlib import Path
from typing import TYPE_CHECKING, Any

from server.cli.broker_options import add_broker_options, broker_config

if TYPE_CHECKING:
    from server.records.drive_wire import Segment
    from server.records.measured_log import MeasuredLog

HELP = "publish a measured log to an MQTT broker at real time (the mqtt source's test feed)"


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("log", type=Path, help="measured log (.csv with .json sidecar, or .mat)")
    p.add_argument("--broker", required=True, help="mqtt://host[:port] or mqtts://host[:port]")
    p.add_argument(
        "--machine",
        required=True,
        help="machine name (the topic's second level); a,b,c: several machines, one log",
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
    add_broker_options(p)
    p.add_argument(
        "--float64", action="store_true", help="send efforts as float64 too (default float32)"
    )
    p.add_argument("--quiet", action="store_true", help="no progress bar")


def run(args: argparse.Namespace) -> int:
    from tqdm import tqdm

    from server.errors import CutwatchError
    from server.pipeline.broker import (
        connect_blocking,
        make_client,
        topic,
    )
    from server.records.measured_log import load_log, load_meta

    if not (0 <= args.speed <= 1000):
        raise CutwatchError(f"--speed: expected a value in [0, 1000], got {args.speed}")
    if not (1 <= args.block_ms <= 1000):
        raise CutwatchError(f"--block-ms: expected a value in [1, 1000], got {args.block_ms}")
    machines = [m.strip() for m in args.machine.split(",") if m.strip()]
    if not machines:
        raise CutwatchError(f"--machine: expected a name or names a,b,c, got {args.machine!r}")
    drive_topics = [topic(m, "drive") for m in machines]
    meta_topics = [topic(m, "meta") for m in machines]
    log = load_log(args.log, meta=load_meta(args.meta), maps=args.map)
    cfg = broker_config(args.broker, args)
    plan = feed_plan(log, args.block_ms, args.float64)
    n = log.n
    client = make_client(cfg, client_id=f"cutwatch-feed-{machines[0]}-{os.getpid()}")
    connect_blocking(client, cfg)
    import paho.mqtt.client as mqtt

    assert isinstance(client, mqtt.Client)
    seq = 0
    m = len(machines)
    try:
        for mt in meta_topics:
            client.publish(mt, plan.meta, qos=1, retain=True).wait_for_publish(10)
        start = time.monotonic()
        info = None
        ts, per = plan.sample_time, plan.per
        with tqdm(
            total=n, desc=f"feed {args.machine[:40]}", unit="sample", unit_scale=True,
            disable=args.quiet,
        ) as bar:  # fmt: skip
            for a in range(0, n, per):
                b = min(n, a + per)
                for k, dt in enumerate(drive_topics):
                    if args.speed > 0:  # published when its last sample is due (+ phase)
                        due = start + (b + k * per / m) * ts / args.speed
                        delay = due - time.monotonic()
                        if delay > 0:
                            time.sleep(delay)
                    info = client.publish(dt, plan.block(seq, a, b, wall=time.time()), qos=0)
                seq += 1
                bar.update(b - a)
        if info is not None:
            info.wait_for_publish(30)
    finally:
        client.loop_stop()
        client.disconnect()
    if not args.quiet:
        where = drive_topics[0] if m == 1 else f"{m} machines' drive topics"
        print(f"published {seq} blocks ({n} samples) to {where} on {cfg.describe()}")
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
        """The identities of samples ``a:b`` as segments: one per run of equal values
        (an identity not known is tool 0 / line 0, an override not known is not sent)."""
        tool = self.ident.get("tool")
        line = self.ident.get("line")
        ovr = self.ident.get("override")
        import numpy as np

        from server.records.drive_wire import Segment

        if tool is None and line is None and ovr is None:
            return []
        n = b - a
        tl = _whole(tool, a, b, n)
        ln = _whole(line, a, b, n)
        ov = ovr[a:b] if ovr is not None else np.full(n, np.nan)
        key = np.column_stack([tl, ln, np.nan_to_num(ov, nan=-1.0)])
        starts = np.flatnonzero(np.r_[True, np.any(key[1:] != key[:-1], axis=1)])
        return [
            Segment(int(i), int(tl[i]), int(ln[i]),
                    None if not (0 < ov[i] <= 3) else float(ov[i]))
            for i in starts
        ]  # fmt: skip


def _whole(v: Any, a: int, b: int, n: int) -> Any:
    """A tool or line identity as whole numbers >= 0 (0: not known)."""
    import numpy as np

    if v is None:
        return np.zeros(n, dtype=np.int64)
    x = np.asarray(v[a:b], dtype=np.float64)
    ok = np.isfinite(x) & (x >= 0)
    return np.where(ok, np.round(np.where(ok, x, 0.0)), 0).astype(np.int64)


def feed_plan(log: MeasuredLog, block_ms: float, float64: bool) -> FeedPlan:
    """The plan of a feed of ``log`` (see :class:`FeedPlan`).

    Raises
    ------
    LogFormatError
        The log does not describe a machine (e.g. a rate outside 10 Hz-10 kHz).
    """
    return FeedPlan(log, block_ms, float64)
