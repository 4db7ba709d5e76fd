"""No function over 120 lines in ``server/`` and ``estimators/`` (issue 19, item 8).

An ast walk, no tool: a function's length is from its ``def`` line (decorators aside) to
its last line, nested functions counted inside their parent and on their own.
"""

from __future__ import annotations

import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
MAX_LINES = 120
CHECKED = ("server", "estimators")


def long_functions(root: Path, packages: tuple[str, ...], limit: int) -> list[str]:
    """``path:line name (n lines)`` of every function over ``limit`` lines, longest first."""
    found: list[tuple[int, str]] = []
    for pkg in packages:
        for path in sorted((root / pkg).rglob("*.py")):
            tree = ast.parse(path.read_text(encoding="utf-8"), filename=str(path))
            for node in ast.walk(tree):
                if isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef):
                    n = (node.end_lineno or node.lineno) - node.lineno + 1
                    if n > limit:
                        where = f"{path.relative_to(root).as_posix()}:{node.lineno}"
                        found.append((n, f"{where} {node.name} ({n} lines)"))
    return [text for _, text in sorted(found, key=lambda f: (-f[0], f[1]))]


def test_the_check_counts_from_def_to_the_last_line(tmp_path: Path) -> None:
    body = "\n".join(f"    x{i} = {i}" for i in range(4))
    (tmp_path / "pkg").mkdir()
    (tmp_path / "pkg" / "m.py").write_text(
        f"@decorator\ndef five():\n{body}\n\n\ndef two():\n    pass\n"
    )
    assert long_functions(tmp_path, ("pkg",), 4) == ["pkg/m.py:2 five (5 lines)"]
    assert long_functions(tmp_path, ("pkg",), 5) == []


def test_no_function_over_120_lines() -> None:
    offenders = long_functions(ROOT, CHECKED, MAX_LINES)
    assert offenders == [], f"functions over {MAX_LINES} lines:\n" + "\n".join(offenders)
