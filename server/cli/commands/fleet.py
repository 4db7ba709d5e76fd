"""Serve the fleet page: one row per machine from ``cutwatch/+/estimates`` and
``cutwatch/+/events`` on a broker.

Every ``cutwatch serve`` or ``cutwatch worker`` that publishes its estimates or its process
monitor's events appears as a row, named by its topic: status (ok, alarm, stale when
silent for --stale-after seconds), the monitor's state (teaching, watching, alarm) and its
newest unacknowledged event (the row red while one waits), force level, flank wear and
remaining life, alarms, last seen, and a link to its page: --machine-url, or the
message's own link when its origin is a --dashboard-origin.

Access is the service's: ``CUTWATCH_TOKEN`` and ``CUTWATCH_VIEW_TOKEN`` (every page and
route but ``/api/health`` then needs a viewer's token or the session of a login at
``/login``), ``CUTWATCH_ALLOWED_HOSTS``; any address other than loopback needs a token.

Examples::

    cutwatch fleet --broker mqtt://127.0.0.1:1883 --port 8100
    cutwatch fleet --broker mqtt://127.0.0.1:1883 --port 8101 \
        --dashboard-origin http://127.0.0.1:8201 --dashboard-origin http://127.0.0.1:8202
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
    p.add_argument(
        "--machine-url",
        help="every row's link: a URL holding {machine}, e.g. http://plant.lan/m/{machine}/",
    )
    p.add_argument(
        "--dashboard-origin",
        action="append",
        default=[],
        help="http(s)://host[:port] of a worker or service whose link a message may carry "
        "(repeat for each); other links are not shown",
    )
    add_broker_options(p)


def run(args: argparse.Namespace) -> int:
    import uvicorn

    from server.errors import CutwatchError
    from server.service.fleet import Links, create_fleet_app
    from server.service.front import uvicorn_options
    from server.service.settings import Settings, check_security

    if not (1 <= args.port <= 65535):
        raise CutwatchError(f"--port: expected 1-65535, got {args.port}")
    if not (args.stale_after > 0):
        raise CutwatchError(f"--stale-after: expected a value > 0, got {args.stale_after}")
    links = Links.parse(args.machine_url, args.dashboard_origin)
    settings = Settings(host=args.host, port=args.port)
    check_security(settings)  # a token off loopback; tokens well formed
    cfg = broker_config(args.broker, args)
    app = create_fleet_app(cfg, stale_after=args.stale_after, settings=settings, links=links)
    # the service's HTTP limits (slow clients dropped) and WebSocket settings
    uvicorn.run(app, host=args.host, port=args.port, log_level="warning",
                **uvicorn_options(settings))  # fmt: skip
    return 0
