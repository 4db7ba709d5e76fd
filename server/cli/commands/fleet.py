"""Serve the fleet page: one row per machine from ``cutwatch/+/estimates`` and
``cutwatch/+/events`` on a broker.

Every ``cutwatch serve`` that publishes its estimates (``CUTWATCH_MQTT_PUBLISH_HZ`` > 0) or
its process monitor's events appears as a row: status (ok, alarm, stale when silent for
--stale-after seconds), the monitor's state (teaching, watching, alarm) and its newest
unacknowledged event (the row red while one waits), force level, flank wear and
remaining life, alarms, last seen, and a link to its dashboard.

Example::

    cutwatch fleet --broker mqtt://127.0.0.1:1883 --port 8100
"""

from __future__ import annotations

import argparse

from server.cli.broker_options import add_broker_options, broker_config

HELP = "serve the fleet page (one row per machine publishing estimates to a broker)"


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--broker", required=True, help="mqtt://host[:port] or mqtts://host[:port]")
    p.add_argument("--host", default="127.0.0.1", help="address to bind")
    p.add_argument("--port", type=int, default=8100, help="HTTP port of the fleet page")
    p.add_argument(
        "--stale-after", type=float, default=5.0, help="seconds of silence before a row is stale"
    )
    add_broker_options(p)


def run(args: argparse.Namespace) -> int:
    import uvicorn

    from server.errors import CutwatchError
    from server.service.fleet import create_fleet_app
    from server.service.http_guard import GuardedHttpToolsProtocol

    if not (1 <= args.port <= 65535):
        raise CutwatchError(f"--port: expected 1-65535, got {args.port}")
    if not (args.stale_after > 0):
        raise CutwatchError(f"--stale-after: expected a value > 0, got {args.stale_after}")
    cfg = broker_config(args.broker, args)
    app = create_fleet_app(cfg, stale_after=args.stale_after)
    # the service's HTTP limits (slow clients dropped; default limits)
    uvicorn.run(
        app, host=args.host, port=args.port, log_level="warning", http=GuardedHttpToolsProtocol
    )
    return 0
