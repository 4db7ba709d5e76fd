"""The tests keep the layering: a test imports only the layer it tests and those below.

The tests of ``common/``, ``machine/`` and ``estimators/`` import nothing of ``server``
(they may use each other: the estimators' tests take the simulated machine as their plant,
the effect-name test checks both against ``common``); those of ``server/records/`` nothing
of the server above records. An ast walk of the imports, nested ones included.
"""

from __future__ import annotations

import ast
from pathlib import Path

TESTS = Path(__file__).resolve().parent
#: test folder -> module prefixes its tests must not import
FORBIDDEN = {
    "common": ("server",),
    "machine": ("server",),
    "estimators": ("server",),
    "records": ("server.pipeline", "server.service", "server.experiments", "server.cli"),
}


def imported(path: Path) -> list[tuple[int, str]]:
    """(line, module) of every import in ``path``."""
    out = []
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
        if isinstance(node, ast.Import):
            out += [(node.lineno, a.name) for a in node.names]
        elif isinstance(node, ast.ImportFrom) and node.module and not node.level:
            out.append((node.lineno, node.module))
    return out


def wrong_way(folder: str, banned: tuple[str, ...]) -> list[str]:
    found = []
    for path in sorted((TESTS / folder).rglob("*.py")):
        for line, mod in imported(path):
            if any(mod == b or mod.startswith(b + ".") for b in banned):
                found.append(f"{path.relative_to(TESTS.parent).as_posix()}:{line} imports {mod}")
    return found


def test_tests_import_only_their_layer_and_below() -> None:
    found = [w for folder, banned in FORBIDDEN.items() for w in wrong_way(folder, banned)]
    assert found == [], "\n".join(found)


def test_the_walk_finds_a_nested_import(tmp_path: Path) -> None:
    (tmp_path / "t.py").write_text("import os\n\n\ndef f():\n    from server.cli import main\n")
    assert imported(tmp_path / "t.py") == [(1, "os"), (5, "server.cli")]
