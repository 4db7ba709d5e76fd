"""The broker options of ``cutwatch serve``, ``feed`` and ``fleet``: one set, one meaning.

Each option's default is the environment variable ``cutwatch serve`` reads for it
(``CUTWATCH_MQTT_USERNAME``, ``CUTWATCH_MQTT_CAFILE``, ``CUTWATCH_MQTT_CERTFILE``,
``CUTWATCH_MQTT_KEYFILE``); the password is only ever read from the environment
(``CUTWATCH_MQTT_PASSWORD``, or the variable ``--password-env`` names), never from the
command line, where any user of the host could read it in the process list.
"""

from __future__ import annotations

import argparse
import os
from pathlib import Path

from server.pipeline.broker import BrokerConfig, parse_broker_url

PASSWORD_ENV = "CUTWATCH_MQTT_PASSWORD"

#: option -> (the environment variable giving its default, help)
_OPTIONS = {
    "username": ("CUTWATCH_MQTT_USERNAME", "broker user name"),
    "cafile": (
        "CUTWATCH_MQTT_CAFILE",
        "CA certificate(s) (PEM) the broker's certificate is checked against; implies TLS",
    ),
    "certfile": (
        "CUTWATCH_MQTT_CERTFILE",
        "this client's certificate (PEM), for a broker that requires one; implies TLS",
    ),
    "keyfile": (
        "CUTWATCH_MQTT_KEYFILE",
        "the private key of --certfile (PEM), when not in the certificate's file",
    ),
}


def add_broker_options(p: argparse.ArgumentParser) -> None:
    """Add ``--username --password-env --cafile --certfile --keyfile`` to ``p``."""
    g = p.add_argument_group(
        "broker connection",
        "mqtts:// (or --cafile/--certfile) connects with TLS, the broker's certificate and "
        "host name verified (docs/broker.md)",
    )
    for name, (env, text) in _OPTIONS.items():
        g.add_argument(
            f"--{name}",
            type=str if name == "username" else Path,
            default=os.environ.get(env) or None,
            help=f"{text} (default: ${env})",
        )
    g.add_argument(
        "--password-env",
        metavar="VAR",
        default=PASSWORD_ENV,
        help="environment variable holding the broker password (never on the command line)",
    )


def broker_settings(args: argparse.Namespace) -> dict[str, str]:
    """The options given, as ``Settings`` fields (``mqtt_username`` ...)."""
    out: dict[str, str | None] = {f"mqtt_{name}": getattr(args, name) for name in _OPTIONS}
    if args.password_env != PASSWORD_ENV:
        out["mqtt_password"] = os.environ.get(args.password_env)
    return {k: v for k, v in out.items() if v is not None}


def broker_config(url: str, args: argparse.Namespace) -> BrokerConfig:
    """The connection of ``url`` with the options given (for ``feed`` and ``fleet``)."""
    return parse_broker_url(
        url,
        username=args.username,
        password=os.environ.get(args.password_env) if args.username else None,
        cafile=args.cafile,
        certfile=args.certfile,
        keyfile=args.keyfile,
    )
