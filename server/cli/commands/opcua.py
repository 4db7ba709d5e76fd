"""OPC UA tools: ``cutwatch opcua browse URL`` prints a starter node map (issue 33).

``browse`` connects as ``serve --source opcua`` would (the same security options), walks
the server's address space for the OPC 40502 (CNC Systems) axes, spindle and channel and
prints a node map: per axis the motor position, the linear scale (then ``two_inertia``),
the commanded position, the drive's torque or force, a vendor's current and velocity;
the spindle's speed, power, torque, load, current; the tool, line, program and override.
Check it, add what the server names otherwise, and give it to ``serve --nodes``
(docs/opcua.md walks from here to a running dashboard).

Examples::

    cutwatch opcua browse opc.tcp://127.0.0.1:4840/cutwatch \\
        --opcua-trust data/opcua-sim/server-cert.der --out map.json
    cutwatch opcua browse opc.tcp://127.0.0.1:4840/cutwatch --opcua-security None \\
        --out open.json          # only when asked by name: a server offering None
"""

from __future__ import annotations

import argparse
from pathlib import Path

from server.cli.opcua_options import add_opcua_options, opcua_security

HELP = "OPC UA tools: browse a CNC's server for a starter node map"


def add_arguments(p: argparse.ArgumentParser) -> None:
    sub = p.add_subparsers(dest="action", metavar="ACTION")
    sub.required = True
    b = sub.add_parser("browse", help="print a starter node map of the server at URL")
    b.add_argument("url", help="the server, opc.tcp://host:port[/path]")
    b.add_argument("--sample-time", type=float, default=0.1, help="the map's sample time [s]")
    b.add_argument("--depth", type=int, default=5, help="levels below Objects to walk")
    b.add_argument("--out", type=Path, help="write the map here instead of printing it")
    add_opcua_options(b)


def run(args: argparse.Namespace) -> int:
    import asyncio
    import json

    from server.errors import CutwatchError
    from server.pipeline.opcua_browse import browse_map

    if not args.url.startswith("opc.tcp://"):
        raise CutwatchError(f"URL {args.url!r}: expected opc.tcp://host:port")
    try:
        m = asyncio.run(browse_map(args.url, opcua_security(args), args.sample_time, args.depth))
    except (OSError, TimeoutError) as exc:
        raise CutwatchError(f"{args.url}: cannot connect ({type(exc).__name__}: {exc})") from None
    text = json.dumps(m, indent=2) + "\n"
    if args.out is not None:
        args.out.write_text(text, encoding="utf-8")
        print(f"node map: {args.out} ({len(m['axes'])} axes)")
    else:
        print(text, end="")
    return 0
