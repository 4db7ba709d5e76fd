"""The ``cutwatch`` command line.

Each sub-command lives in its own module in :mod:`server.cli.commands`, which defines
``HELP`` (one line), ``add_arguments(parser)`` and ``run(args) -> int``. Modules are
found by name, so adding a command never edits this file.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence

from server.cli import commands
from server.plugins import plugin_modules, short_name

DESCRIPTION = """\
cutwatch watches a machining cut through the machine tool's own drive signals: motor
current, motor encoder and linear scale. It simulates a two-inertia ball-screw stage,
runs the cutting-force observers and adaptive identification of the papers in
../shared/seeds, reproduces their experiments, analyses recorded logs, and serves a live
dashboard.
"""


class _HelpFormatter(argparse.RawDescriptionHelpFormatter):
    """Keeps the commands' own line breaks and shows each option's default (unless its
    help already says it, or there is none)."""

    def _get_help_string(self, action: argparse.Action) -> str:
        text = action.help or ""
        d = action.default
        if (
            "default" in text
            or d is None
            or d is argparse.SUPPRESS
            or isinstance(d, bool)
            or d == []
        ):
            return text
        return f"{text} (default: %(default)s)"


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="cutwatch",
        description=DESCRIPTION,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    sub.required = True
    for mod in plugin_modules(commands):
        name = getattr(mod, "COMMAND", short_name(mod))
        p = sub.add_parser(
            name,
            help=mod.HELP,
            description=(mod.__doc__ or mod.HELP),
            formatter_class=_HelpFormatter,
        )
        mod.add_arguments(p)
        p.set_defaults(_run=mod.run)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        rc = int(args._run(args))
    except KeyboardInterrupt:
        return 130
    except Exception as exc:  # a named error at a boundary: print it, no traceback
        from server.errors import is_user_error

        if not is_user_error(exc):
            raise
        print(f"cutwatch {args.command}: error: {exc}", file=sys.stderr)
        return 2
    return rc


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
