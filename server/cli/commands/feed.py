"""Publish a measured log to an MQTT broker at real time, as a machine's edge device would.

Each block of ``--block-ms`` of samples goes to ``cutwatch/<machine>/drive`` in the
binary wire format (docs/broker.md); the sidecar goes first to ``cutwatch/<machine>/meta``
as a retained message. This is the tool to test the ``mqtt`` source of ``cutwatch serve``
and to demonstrate it: any log ``cutwatch replay``/``residual`` read (CSV + sidecar, or a
``.mat`` file with ``--map``) can be fed.

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
"""

from __future__ import annotations

import argparse
import os
import time
from pathlib import Path

from server.cli.broker_options import add_broker_options, broker_config

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
    from server.records.drive_wire import encode_drive, encode_meta
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
    ts = log.sample_time
    n = log.n
    per = max(1, int(round(args.block_ms * 1e-3 / ts)))
    # the effort travels as tau_m, or as i_m when the log gives a current (unit A)
    effort = "i_m" if log.units.get("effort") == "A" else "tau_m"
    source = {effort: "tau_m", "q_m": "q_m", "q_l": "q_l", "f_ext": "f_ext"}
    names = [k for k, c in source.items() if c in log.columns]
    units = {
        "effort": "N m" if effort == "i_m" else log.units.get("effort", "N m"),
        "position": log.units.get("position", "rad"),
        "current": "A",
    }
    dtypes = {k: "<f8" for k in names} if args.float64 else None
    sidecar = dict(log.sidecar)
    sidecar["sample_time"] = ts
    sidecar["units"] = {"effort": log.units.get("effort", "N m"), "position": units["position"]}
    sidecar.setdefault("kind", log.kind)

    client = make_client(cfg, client_id=f"cutwatch-feed-{machines[0]}-{os.getpid()}")
    connect_blocking(client, cfg)
    import paho.mqtt.client as mqtt

    assert isinstance(client, mqtt.Client)
    seq = 0
    try:
        for mt in meta_topics:
            client.publish(mt, encode_meta(sidecar), qos=1, retain=True).wait_for_publish(10)
        t_col = log.columns["t"]
        start = time.monotonic()
        info = None
        m = len(machines)
        with tqdm(
            total=n, desc=f"feed {args.machine[:40]}", unit="sample", unit_scale=True,
            disable=args.quiet,
        ) as bar:  # fmt: skip
            for a in range(0, n, per):
                b = min(n, a + per)
                cols = {k: log.columns[source[k]][a:b] for k in names}
                for k, dt in enumerate(drive_topics):
                    if args.speed > 0:  # published when its last sample is due (+ phase)
                        due = start + (b + k * per / m) * ts / args.speed
                        delay = due - time.monotonic()
                        if delay > 0:
                            time.sleep(delay)
                    payload = encode_drive(
                        seq, float(t_col[a] - t_col[0]), ts, cols, units, dtypes, wall=time.time()
                    )
                    info = client.publish(dt, payload, qos=0)
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
