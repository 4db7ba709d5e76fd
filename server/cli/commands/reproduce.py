"""Reproduce a paper's experiment: our numbers beside the paper's, and the checks.

Examples::

    cutwatch reproduce --list
    cutwatch reproduce adaptive-observer --plot out/figs
    cutwatch reproduce --all --quick --json   # every experiment, shortened runs

Exit status: 0 when every check holds, 1 when one does not (marked FAIL in the table,
"holds": false in the JSON; the rows are printed all the same), 2 for bad input.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

HELP = "reproduce a paper's experiment (ours beside the paper's)"


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("name", nargs="*", help="experiment name(s); see --list")
    p.add_argument("--all", action="store_true", help="run every experiment")
    p.add_argument("--list", action="store_true", help="list the experiments and their rows")
    p.add_argument("--json", action="store_true", help="print one JSON object per experiment")
    p.add_argument("--plot", metavar="DIR", type=Path, help="write the figures as PNG into DIR")
    p.add_argument(
        "--quick", action="store_true", help="reduced run length (the checks still hold); for tests"
    )


def run(args: argparse.Namespace) -> int:
    from server.errors import CutwatchError
    from server.experiments.reproduction import discover, format_table

    mods = discover()
    if args.list:
        for name, mod in mods.items():
            print(f"{name:28s} {mod.SOURCE}")
            for row in getattr(mod, "ROWS", ()):
                print(f"    {row}")
        return 0
    names = list(mods) if args.all else list(args.name)
    if not names:
        raise CutwatchError("name an experiment or pass --all; known: " + ", ".join(mods))
    unknown = [n for n in names if n not in mods]
    if unknown:
        raise CutwatchError(f"unknown experiment {unknown[0]!r}; known: {', '.join(mods)}")
    ok = True
    out = []
    for name in names:
        rep = mods[name].run(quick=args.quick, plot_dir=args.plot, progress=not args.json)
        ok = ok and rep.all_hold
        if args.json:
            out.append(rep.to_json())
        else:
            print(format_table(rep))
            print()
    if args.json:
        json.dump(out[0] if len(out) == 1 else out, sys.stdout, indent=2)
        print()
    return 0 if ok else 1
