"""The OPC UA connection's options, shared by ``serve``, ``worker`` and ``opcua browse``."""

from __future__ import annotations

import argparse
from pathlib import Path

from server.pipeline.opcua_link import POLICIES, OpcuaSecurity


def add_opcua_options(p: argparse.ArgumentParser) -> None:
    """Add the security options of an OPC UA client."""
    g = p.add_argument_group("OPC UA security (docs/opcua.md)")
    g.add_argument(
        "--opcua-security",
        default="best",
        choices=("best", *POLICIES, "None"),
        help="security policy, always SignAndEncrypt: best = the strongest the server "
        "offers of Aes256_Sha256_RsaPss, Aes128_Sha256_RsaOaep, Basic256Sha256 (the "
        "floor); None only when named (default best)",
    )
    g.add_argument("--opcua-cert", type=Path, help="this client's certificate (DER or PEM)")
    g.add_argument("--opcua-key", type=Path, help="this client's private key (PEM)")
    g.add_argument(
        "--opcua-trust",
        type=Path,
        action="append",
        default=[],
        metavar="PATH",
        help="a trusted server certificate, or a folder of them; repeatable (a server not "
        "in the list is refused, its thumbprint named)",
    )
    g.add_argument(
        "--opcua-cert-dir",
        type=Path,
        help="where a self-signed client certificate is made when --opcua-cert is not given "
        "(default: data/opcua; serve: its data directory's opcua/)",
    )


def opcua_security(args: argparse.Namespace) -> OpcuaSecurity:
    """The security the options say (user and password: CUTWATCH_OPCUA_USER and
    CUTWATCH_OPCUA_PASSWORD in the environment)."""
    return OpcuaSecurity(
        policy=args.opcua_security,
        certificate=args.opcua_cert,
        private_key=args.opcua_key,
        trust=tuple(args.opcua_trust),
        cert_dir=args.opcua_cert_dir or Path("data/opcua"),
    )
