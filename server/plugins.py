"""Modules found by name: the sub-commands, reproductions and benchmark groups.

A package of plugins is a folder of modules; adding one never edits a list. Modules
whose name starts with ``_`` are helpers, not plugins.
"""

from __future__ import annotations

import importlib
import pkgutil
from types import ModuleType


def plugin_modules(package: ModuleType) -> list[ModuleType]:
    """Every public module of ``package`` (name not starting with ``_``), imported, in
    order of module name."""
    infos = sorted(pkgutil.iter_modules(package.__path__), key=lambda i: i.name)
    return [
        importlib.import_module(f"{package.__name__}.{info.name}")
        for info in infos
        if not info.name.startswith("_")
    ]


def short_name(module: ModuleType) -> str:
    """The last part of a module's dotted name (``server.cli.commands.bench`` -> ``bench``)."""
    return module.__name__.rpartition(".")[2]
