"""Serve the live dashboard: the simulated machine and its observers, streamed.

Examples::

    cutwatch serve                       # http://127.0.0.1:8000/ (the machining centre)
    cutwatch serve --scenario default    # the seeds' machines side by side
    cutwatch serve --speed 0             # start paused
    CUTWATCH_TOKEN="$(openssl rand -hex 16)" cutwatch serve --host 0.0.0.0
    cutwatch serve --source mqtt --broker mqtt://127.0.0.1:1883 --machine mill-1 \
        --publish-hz 10                  # a real machine's drive data from a broker
    cutwatch serve --source opcua --opcua opc.tcp://cnc-7:4840 --nodes map.json \
        --opcua-trust cnc-7.der          # a CNC's OPC UA server (docs/opcua.md)
    cutwatch serve --source mqtt --broker mqtt://127.0.0.1:1883 --machine emps \
        --model axis=out/emps/report.json  # the residual loop's effects in the live model

Options override the ``CUTWATCH_*`` environment variables. Any address other than
loopback requires ``CUTWATCH_TOKEN`` (16 characters at least; the service refuses to
start without it). With a token set every request but ``/api/health`` needs one:
``Authorization: Bearer <token>``, or the browser's session after logging in at
``/login``; ``CUTWATCH_VIEW_TOKEN`` is a second token that only reads and streams.
"""

from __future__ import annotations

import argparse
from typing import TYPE_CHECKING

from server.cli.broker_options import add_broker_options, broker_settings
from server.cli.opcua_options import add_opcua_options

if TYPE_CHECKING:
    from server.service.settings import Settings

HELP = "serve the live dashboard, REST API and WebSocket stream (one uvicorn worker)"


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--host", help="address to bind (default 127.0.0.1)")
    p.add_argument("--port", type=int, help="HTTP port (default 8000)")
    p.add_argument(
        "--viser-port",
        type=int,
        help="loopback port of the viser 3D view, reached at /viser/ (default 8080)",
    )
    p.add_argument(
        "--scenario",
        help="scenario at start (see GET /api/scenarios; default: machining-centre, the "
        "3-axis machining centre; 'default': the seeds' machines side by side, the default "
        "before issue 31)",
    )
    p.add_argument(
        "--speed",
        type=float,
        help="simulated seconds per wall second; 0 = start paused (default 1)",
    )
    p.add_argument("--no-viser", action="store_true", help="do not start the viser 3D view")
    p.add_argument(
        "--source",
        choices=("simulator", "mqtt", "opcua"),
        help="measurements from the simulated machine (default), a broker (--broker) or a "
        "CNC's OPC UA server (--opcua, --nodes)",
    )
    p.add_argument("--opcua", metavar="URL", help="the CNC's OPC UA server, opc.tcp://host:port")
    p.add_argument(
        "--opcua-publishing",
        type=float,
        metavar="S",
        help="the OPC UA subscription's publishing interval [s] (default: the map's sample "
        "time, at least 0.1 s)",
    )
    p.add_argument(
        "--nodes",
        metavar="MAP.json",
        help="the OPC UA node map (`cutwatch opcua browse URL` prints a starter one)",
    )
    p.add_argument(
        "--broker",
        help="MQTT broker URL mqtt://host[:port] or mqtts://host[:port] (TLS; docs/broker.md)",
    )
    p.add_argument("--machine", help="machine name on the broker (topics cutwatch/<machine>/...)")
    p.add_argument(
        "--publish-hz",
        type=float,
        help="publish estimates on cutwatch/<machine>/estimates at this rate (default 0: off)",
    )
    p.add_argument(
        "--data-dir",
        help="the service's recordings/, uploads/, reports/ and history/ (default ./data)",
    )
    p.add_argument(
        "--history-url",
        help="database of the kept events and tool lives: a SQLAlchemy URL (default SQLite "
        "DATA_DIR/history/cutwatch.sqlite; 'none': keep none)",
    )
    p.add_argument(
        "--part",
        action="append",
        metavar="MODULE:ATTR",
        help="add a live part (a class or factory on the Python path) to every pipeline; "
        "repeatable (CUTWATCH_PARTS; docs/adding-a-part.md)",
    )
    p.add_argument(
        "--model",
        action="append",
        metavar="[AXIS=]REPORT.json",
        help="load the effects a residual report (cutwatch residual) selected into the live "
        "rigid model of AXIS (default: every axis of the feed's machine); their coefficients "
        "are identified live with M, Fv, Fc, and the dashboard shows the process force with "
        "and without them; repeatable (CUTWATCH_MODEL; docs/live-axis.md)",
    )
    p.add_argument("--log-level", default="warning", help="uvicorn log level")
    add_broker_options(p)
    add_opcua_options(p)


def build_settings(args: argparse.Namespace) -> Settings:
    """Settings from the environment, overridden by the options given."""
    from pydantic import ValidationError

    from server.errors import CutwatchError
    from server.service.settings import Settings as _Settings

    overrides = {
        k: v
        for k, v in {
            "host": args.host,
            "port": args.port,
            "viser_port": args.viser_port,
            "scenario": args.scenario,
            "speed": args.speed,
            "viser": False if args.no_viser else None,
            "source": args.source,
            "mqtt_broker": args.broker,
            "mqtt_machine": args.machine,
            "mqtt_publish_hz": args.publish_hz,
            "data_dir": args.data_dir,
            "history_url": args.history_url,
            "parts": ",".join(args.part) if args.part else None,
            "opcua_url": args.opcua,
            "opcua_nodes": args.nodes,
            "opcua_publishing_s": args.opcua_publishing,
            "opcua_security": None if args.opcua_security == "best" else args.opcua_security,
            "opcua_cert": args.opcua_cert,
            "opcua_key": args.opcua_key,
            "opcua_trust": ",".join(str(t) for t in args.opcua_trust) or None,
            "opcua_cert_dir": args.opcua_cert_dir,
            "model": ",".join(args.model) if args.model else None,
        }.items()
        if v is not None
    }
    overrides.update(broker_settings(args))
    try:
        return _Settings(**overrides)
    except ValidationError as exc:
        first = exc.errors()[0]
        field = ".".join(str(x) for x in first["loc"])
        raise CutwatchError(f"{field}: {first['msg']}, got {first.get('input')!r}") from None


def run(args: argparse.Namespace) -> int:
    import uvicorn

    from server.pipeline import part_registry
    from server.service.app import create_app
    from server.service.front import uvicorn_options

    settings = build_settings(args)
    part_registry.use(settings.parts)  # a part that cannot be loaded: said before serving
    app = create_app(settings)
    if settings.viser:
        from server.service.viser_scene import VISER_HOST, check_port_free

        check_port_free(VISER_HOST, settings.viser_port)  # fail before serving anything
    shown = "127.0.0.1" if settings.host in ("0.0.0.0", "::") else settings.host
    print(
        f"cutwatch dashboard: http://{shown}:{settings.port}/  "
        f"(API docs: http://{shown}:{settings.port}/docs)",
        flush=True,
    )
    if settings.viser:
        print(
            f"viser 3D view: http://{shown}:{settings.port}/viser/  "
            f"(viser itself on 127.0.0.1:{settings.viser_port} only)",
            flush=True,
        )
    uvicorn.run(
        app,
        host=settings.host,
        port=settings.port,
        log_level=args.log_level,
        **uvicorn_options(settings),
    )
    return 0
