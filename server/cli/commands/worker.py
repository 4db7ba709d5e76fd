"""Run the pipelines of many machines in one process: a plant's worker.

The worker owns a shard of the plant's machines (``--shard I/N``: the machines whose
name's SHA-256 hash is I modulo N; ``host/N`` takes I from the host name's ordinal, as a
Kubernetes StatefulSet's pod ``cutwatch-worker-3`` has it) or an explicit list
(``--machines``). It learns the machines from their retained ``cutwatch/<machine>/meta``,
subscribes to the drive blocks of its own machines only, over one broker connection,
runs each machine's live pipeline with blocks of ``--block-ms`` (100: estimates at
10 Hz), and publishes ``cutwatch/<machine>/estimates`` and ``.../events`` (QoS 1). It has
no dashboard or 3D view per machine: one small HTTP server (``--port``) gives
``/api/health`` for the probes and a page per machine at ``/m/<machine>/`` (the fleet
page's link), with the service's tokens and login.

Each machine's state is written to ``DATA_DIR/state/<machine>.npz`` every
``--checkpoint-s`` seconds and at SIGTERM; a restarted worker resumes every machine from
its file (wear, identified parameters and covariances carry on). docs/plant.md has the
systemd unit and the Kubernetes StatefulSet that restart a worker.

It also reads machines from their CNCs' OPC UA servers (``--opcua-machine
NAME=URL,nodes=MAP[,security=POLICY][,trust=CERT]...[,cert=PEM,key=PEM][,publishing=S]``,
repeatable, or ``--opcua-machines FILE``: ``{"machines": {NAME: {"url": ..., "nodes": ...,
"trust": [...]}}}``, paths relative to the file): each on its own client (security,
reconnects, health as in ``serve --source opcua``, docs/opcua.md), its estimates and
events published on the broker as a broker machine's. What an entry leaves out comes from
the ``--opcua-*`` options. With OPC UA machines, ``--shard``/``--machines`` may be left out
(then no machine is taken from the broker).

Examples::

    cutwatch worker --broker mqtt://127.0.0.1:1883 --shard 0/2 --data-dir plant --port 8201
    cutwatch worker --broker mqtt://127.0.0.1:1883 --machines mill-1,mill-2 \\
        --data-dir plant --port 8202 --public-url http://127.0.0.1:8202
    cutwatch worker --broker mqtt://127.0.0.1:1883 --port 8203 --opcua-machine \
        cnc-7=opc.tcp://127.0.0.1:4840/cutwatch,nodes=map.json,trust=data/opcua-sim/server-cert.der
"""

from __future__ import annotations

import argparse
from pathlib import Path

from server.cli.broker_options import add_broker_options, broker_config
from server.cli.opcua_options import add_opcua_options, opcua_security

HELP = "run many machines' pipelines in one process (a shard of a plant), no dashboards"


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--broker", required=True, help="mqtt://host[:port] or mqtts://host[:port]")
    who = p.add_mutually_exclusive_group()
    who.add_argument(
        "--shard",
        help="I/N: the machines whose name hashes to shard I of N; host/N: I from the host "
        "name's trailing -<ordinal> (a StatefulSet pod)",
    )
    who.add_argument("--machines", help="an explicit comma-separated list of machine names")
    p.add_argument(
        "--opcua-machine",
        action="append",
        default=[],
        metavar="NAME=URL,nodes=MAP[,KEY=VALUE...]",
        help="a machine read from its OPC UA server; keys: nodes (the node map), security, "
        "trust (repeatable), cert, key, publishing [s]; repeatable",
    )
    p.add_argument(
        "--opcua-machines",
        type=Path,
        metavar="FILE",
        help='OPC UA machines in a JSON file: {"machines": {NAME: {"url": ..., "nodes": ..., '
        '"security": ..., "trust": [...]}}} (paths relative to the file)',
    )
    p.add_argument(
        "--data-dir",
        type=Path,
        help="where state/<machine>.npz checkpoints are kept (default: none kept)",
    )
    p.add_argument(
        "--block-ms", type=float, default=100.0, help="pipeline block [ms of feed]; 100 = 10 Hz"
    )
    p.add_argument("--publish-hz", type=float, default=10.0, help="estimates per machine [1/s]")
    p.add_argument(
        "--checkpoint-s", type=float, default=5.0, help="seconds between a machine's checkpoints"
    )
    p.add_argument("--host", default="127.0.0.1", help="address of the HTTP server to bind")
    p.add_argument("--port", type=int, default=8200, help="HTTP port (health, machine pages)")
    p.add_argument(
        "--public-url",
        help="this worker's URL as browsers reach it; the fleet rows link <url>/m/<machine>/",
    )
    p.add_argument("--seed", type=int, default=0, help="seed of the pipelines")
    p.add_argument(
        "--part",
        action="append",
        metavar="MODULE:ATTR",
        help="add a live part (a class or factory on the Python path) to every machine's "
        "pipeline; repeatable (CUTWATCH_PARTS; docs/adding-a-part.md)",
    )
    add_broker_options(p)
    add_opcua_options(p)


def run(args: argparse.Namespace) -> int:
    import uvicorn

    from common.errors import ParameterError
    from harness.shards import parse_shard
    from server.errors import CutwatchError
    from server.pipeline.broker import check_machine
    from server.pipeline.worker import Worker, WorkerConfig
    from server.service.front import uvicorn_options
    from server.service.settings import Settings, check_security
    from server.service.worker_app import create_worker_app

    if not (1 <= args.port <= 65535):
        raise CutwatchError(f"--port: expected 1-65535, got {args.port}")
    from server.pipeline.opcua_machines import load_opcua_machines, parse_opcua_machine
    from server.records.opcua_map import load_node_map

    sec = opcua_security(args)
    ua = [parse_opcua_machine(s, sec) for s in args.opcua_machine]
    if args.opcua_machines is not None:
        ua += load_opcua_machines(args.opcua_machines, sec)
    seen: set[str] = set()
    for m in ua:
        if m.name in seen:
            raise CutwatchError(f"OPC UA machine {m.name}: expected once, got it twice")
        seen.add(m.name)
        load_node_map(m.nodes)  # a bad map refused now, its key named
    if not (args.shard or args.machines is not None or ua):
        raise CutwatchError(
            "expected --shard, --machines or OPC UA machines (--opcua-machine, "
            "--opcua-machines), got none"
        )
    shard = parse_shard(args.shard) if args.shard else None
    machines = None
    if args.machines is not None:
        names = [m.strip() for m in args.machines.split(",") if m.strip()]
        if not names:
            raise CutwatchError(f"--machines: expected machine names, got {args.machines!r}")
        machines = frozenset(check_machine(m) for m in names)
    try:
        cfg = WorkerConfig(
            shard=shard,
            machines=machines,
            data_dir=args.data_dir,
            block_ms=args.block_ms,
            publish_hz=args.publish_hz,
            checkpoint_s=args.checkpoint_s,
            dashboard=args.public_url,
            seed=args.seed,
            opcua=tuple(ua),
        )
    except ParameterError as exc:
        raise CutwatchError(f"--{exc.name.replace('_', '-')}: expected {exc.expected}, "
                            f"got {exc.got!r}") from exc  # fmt: skip
    from server.pipeline import part_registry

    settings = Settings(host=args.host, port=args.port)
    check_security(settings)
    part_registry.use([*settings.parts.split(","), *(args.part or [])])
    worker = Worker(broker_config(args.broker, args), cfg)
    app = create_worker_app(worker, settings)  # its log lines on stderr from here
    print(f"cutwatch worker ({cfg.describe()}): http://{args.host}:{args.port}/api/health",
          flush=True)  # fmt: skip
    # every process's HTTP limits (slow clients dropped) and WebSocket settings
    uvicorn.run(app, host=args.host, port=args.port, log_level="warning",
                **uvicorn_options(settings))  # fmt: skip
    return 0
