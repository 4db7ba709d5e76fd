"""Write the live stream's message schema, from its models (server/service/messages.py).

Without ``--js``: the JSON Schema of every stream message (hello, channel, data, health,
accuracy), each with its ``x-version``, and the stream's version. With ``--js``: the
dashboard's ES module ``web/schema.js`` (the field lists ``web/protocol.js`` checks every
message against); the test suite fails when the file in the tree differs from it, so after
changing a message model run ``make schema``.

Examples::

    cutwatch schema --js --out web/schema.js     # what `make schema` runs
    cutwatch schema --js --check web/schema.js   # exit 1 when the file is stale
    cutwatch schema                              # the JSON Schema, on stdout
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

HELP = "write the stream's message schema (JSON Schema, or the dashboard's web/schema.js)"


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "--js", action="store_true", help="the dashboard's ES module instead of JSON Schema"
    )
    out = p.add_mutually_exclusive_group()
    out.add_argument("--out", type=Path, default=None, help="write to this file (default stdout)")
    out.add_argument(
        "--check",
        type=Path,
        default=None,
        metavar="FILE",
        help="write nothing; exit 1 (naming the file) when FILE differs from what would be written",
    )


def text(js: bool) -> str:
    """What the command writes: the JS module or the JSON Schema document."""
    from server.service import messages, protocol

    if js:
        return protocol.javascript()
    doc = {
        "title": "cutwatch live stream",
        "version": messages.VERSION,
        "messages": {name: model.model_json_schema() for name, model in messages.MESSAGES.items()},
    }
    return json.dumps(doc, indent=2) + "\n"


def run(args: argparse.Namespace) -> int:
    from server.errors import CutwatchError

    out = text(args.js)
    if args.check is not None:
        try:
            found = args.check.read_text(encoding="utf-8")
        except OSError as exc:
            raise CutwatchError(f"--check: cannot read {args.check}: {exc.strerror}") from exc
        if found != out:
            print(
                f"cutwatch schema: {args.check} is stale: regenerate it with "
                f"`cutwatch schema{' --js' if args.js else ''} --out {args.check}`",
                file=sys.stderr,
            )
            return 1
        return 0
    if args.out is None:
        sys.stdout.write(out)
    else:
        args.out.write_text(out, encoding="utf-8")
    return 0
