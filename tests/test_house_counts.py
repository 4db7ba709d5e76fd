"""The counting script of issue 34 (``tests/_house_counts.py``) counts what it says.

Each test writes a small package and checks the places counted, so a count the issue's
note quotes cannot silently miss a spelling (an alias, a string annotation, a TypedDict).
"""

from __future__ import annotations

from pathlib import Path

from _house_counts import count, summary


def _tree(tmp_path: Path, files: dict[str, str]) -> Path:
    for name, text in files.items():
        path = tmp_path / "pkg" / name
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(text, encoding="utf-8")
    return tmp_path


def _places(tmp_path: Path, metric: str, files: dict[str, str]) -> list[str]:
    return count(_tree(tmp_path, files), ("pkg",)).places.get(metric, [])


def test_loose_dicts_and_their_aliases_are_counted_at_each_use(tmp_path: Path) -> None:
    src = (
        "from typing import Any, Mapping, TypedDict, TypeAlias, cast\n"
        "Blob = dict[str, Any]\n"
        "Other: TypeAlias = 'Mapping[str, object]'\n"
        "class Row(TypedDict):\n    a: int\n    b: Any\n"
        "class Typed(TypedDict):\n    a: int\n"
        "def f(x: dict[str, Any], y: 'dict[str, object] | None') -> list[Blob]:\n"
        "    z: Other = {}\n    w: dict[str, float] = {}\n"
        "    return [cast(dict[str, Any], x), cast(Row, z)]\n"
        "def g(t: Typed, r: Row) -> Mapping[str, int]:\n    return {}\n"
    )
    got = _places(tmp_path, "loose_dicts", {"m.py": src})
    whats = sorted(p.split(" ", 1)[1] for p in got)
    assert whats == sorted(
        [
            "alias of dict[str, Any]",  # Blob's definition
            "alias of Mapping[str, object]",  # Other's (a string annotation parsed)
            "Any-valued TypedDict Row",
            "dict[str, Any]",  # x
            "dict[str, object]",  # y
            "alias Blob",  # the return
            "alias Other",  # z
            "dict[str, Any]",  # the first cast
            "alias Row",  # the second cast
            "alias Row",  # r
        ]
    )


def test_an_alias_imported_into_another_module_is_counted_there(tmp_path: Path) -> None:
    files = {
        "a.py": "from typing import Any\nBlob = dict[str, Any]\n",
        "b.py": "from pkg.a import Blob\ndef f(x: Blob) -> None: ...\n",
    }
    got = _places(tmp_path, "loose_dicts", files)
    assert sorted(got) == ["pkg/a.py:2 alias of dict[str, Any]", "pkg/b.py:2 alias Blob"]


def test_event_kind_vocabularies_are_counted_by_module(tmp_path: Path) -> None:
    files = {
        "defines.py": 'KINDS = ("breakage", "collision")\nX: "Literal[\'wear_limit\']"\n',
        "literal.py": 'from typing import Literal\nK = Literal["breakage", "life_short"]\n',
        "keys.py": 'SIZES = {"breakage": 1.0, "missing_tool": 2.0}\n',
        "uses.py": '"""Docstring: breakage."""\ndef f(k):\n    return k == "breakage"\n',
        "one.py": 'ONLY = ("breakage", "other")\n',
        "enum.py": 'class K(StrEnum):\n    A = "collision"\n    B = "life_short"\n',
    }
    table = summary(count(_tree(tmp_path, files), ("pkg",)))
    found = count(tmp_path, ("pkg",)).places
    vocab = sorted({p.split(":")[0] for p in found["event_kind_vocabularies"]})
    assert vocab == ["pkg/defines.py", "pkg/enum.py", "pkg/keys.py", "pkg/literal.py"]
    literals = sorted({p.split(":")[0] for p in found["event_kind_literals"]})
    assert literals == [
        "pkg/defines.py",
        "pkg/enum.py",
        "pkg/keys.py",
        "pkg/literal.py",
        "pkg/one.py",
        "pkg/uses.py",
    ]
    assert table["event_kind_vocabularies"]["total"] == 4


def test_long_positional_functions_leave_self_aside(tmp_path: Path) -> None:
    args13 = ", ".join(f"a{i}" for i in range(13))
    args12 = ", ".join(f"a{i}" for i in range(12))
    src = (
        f"def long({args13}): ...\n"
        f"def short({args12}, *, k1, k2, k3): ...\n"
        f"class C:\n    def m(self, {args12}): ...\n"
    )
    assert _places(tmp_path, "long_positional", {"m.py": src}) == ["pkg/m.py:1 long (13)"]


def test_duplicate_concepts_and_stand_ins(tmp_path: Path) -> None:
    files = {
        "a.py": "class Channel: ...\nKnobValue = float | str\n",
        "b.py": "class Channel: ...\ndrives = type('drives', (), {'p': 1})()\n",
        "c.py": "Klass = type('Klass', (object,), {})\n",
        "x/store.py": "",
        "y/store.py": "",
    }
    found = count(_tree(tmp_path, files), ("pkg",)).places
    assert found["duplicate_concepts"] == [
        "pkg/b.py:1 Channel (also pkg/a.py)",
        "pkg/x/store.py:1 module name store.py",
        "pkg/y/store.py:1 module name store.py",
    ]
    assert found["stand_ins"] == ["pkg/b.py:2 'drives'"]
