"""Serve the simulated machining centre as a CNC's OPC UA server (issue 33).

The OPC Foundation's CNC NodeSet (OPC 40502) is imported and the machine's axes X, Y, Z,
its spindle S and a channel are instances of its types under ``Objects/CncInterface``;
the values change every ``--sample-time`` with their source timestamps (docs/opcua.md
lists the nodes). The server's certificate is made once in ``--cert-dir`` (its path and
thumbprint are printed: give the file to the client's ``--opcua-trust``).

Examples::

    cutwatch opcua-sim --port 4840                     # Basic256Sha256 and Aes, signed+encrypted
    cutwatch opcua browse opc.tcp://127.0.0.1:4840/cutwatch \\
        --opcua-trust data/opcua-sim/server-cert.der --out map.json
    cutwatch serve --source opcua --opcua opc.tcp://127.0.0.1:4840/cutwatch --nodes map.json \\
        --opcua-trust data/opcua-sim/server-cert.der
"""

from __future__ import annotations

import argparse
from pathlib import Path

COMMAND = "opcua-sim"
HELP = "serve the simulated machining centre as a CNC's OPC UA server (the CNC NodeSet)"


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--host", default="127.0.0.1", help="address to bind")
    p.add_argument("--port", type=int, default=4840, help="TCP port")
    p.add_argument("--sample-time", type=float, default=0.1, help="seconds between values")
    p.add_argument("--seed", type=int, default=0, help="seed of the simulated machine")
    p.add_argument(
        "--security",
        default="secure",
        choices=("secure", "none", "both"),
        help="secure: Basic256Sha256 and the Aes profiles, SignAndEncrypt; none: no security; both",
    )
    p.add_argument(
        "--cert-dir", type=Path, default=Path("data/opcua-sim"), help="the server's certificate"
    )


def run(args: argparse.Namespace) -> int:
    import asyncio

    from server.pipeline.opcua_link import thumbprint
    from server.pipeline.opcua_sim import SimOptions, run_sim

    opts = SimOptions(
        host=args.host, port=args.port, sample_time=args.sample_time, seed=args.seed,
        security=args.security, cert_dir=args.cert_dir,
    )  # fmt: skip

    def ready() -> None:
        print(f"cutwatch opcua-sim: {opts.url}  (security {opts.security})", flush=True)
        if opts.security != "none":
            tp = thumbprint(opts.certificate.read_bytes())
            print(f"server certificate: {opts.certificate}  (thumbprint {tp})", flush=True)

    try:
        asyncio.run(run_sim(opts, ready=ready))
    except KeyboardInterrupt:
        return 0
    return 0
