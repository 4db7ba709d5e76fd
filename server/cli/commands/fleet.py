"""Serve the fleet page: one row per machine from ``cutwatch/+/estimates`` on a broker.

Every ``cutwatch serve`` that publishes its estimates (``CUTWATCH_MQTT_PUBLISH_HZ`` > 0)
appears as a row: status (ok, alarm, stale when silent for --stale-after seconds), force
level, flank wear and remaining life, alarms, last seen, and a link to its dashboard.

Example::

    cutwatch fleet --broker mqtt://127.0.0.1:1883 --port 8100
"""

from __future__ import annotations

import argparse
import os
from pathlib import Path

HELP = "serve the fleet page (one row per machine publishing estimates to a broker)"


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--broker", required=True, help="mqtt://host[:port] or mqtts://host[:port]")
    p.add_argument("--host", default="127.0.0.1", help="address to bind")
    p.add_argument("--port", type=int, default=8100, help="HTTP port of the fleet page")
    p.add_argument(
        "--stale-after", type=float, default=5.0, help="seconds of silence before a row is stale"
    )
    p.add_argument("--username", help="broker user name")
    p.add_argument(
        "--password-env",
        metavar="VAR",
        default="CUTWATCH_MQTT_PASSWORD",
        help="environment variable holding the broker password",
    )
    p.add_argument("--cafile", type=Path, help="CA certificate file: connect with TLS")


def run(args: argparse.Namespace) -> int:
    import uvicorn

    from server.errors import CutwatchError
    from server.pipeline.broker import parse_broker_url
    from server.service.fleet import create_fleet_app

    if not (1 <= args.port <= 65535):
        raise CutwatchError(f"--port: expected 1-65535, got {args.port}")
    if not (args.stale_after > 0):
        raise CutwatchError(f"--stale-after: expected a value > 0, got {args.stale_after}")
    cfg = parse_broker_url(
        args.broker,
        username=args.username,
        password=os.environ.get(args.password_env) if args.username else None,
        cafile=args.cafile,
    )
    app = create_fleet_app(cfg, stale_after=args.stale_after)
    uvicorn.run(app, host=args.host, port=args.port, log_level="warning")
    return 0
