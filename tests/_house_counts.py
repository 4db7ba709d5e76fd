"""The counts of issue 34 ("the rest of the house"), read from the source by an ast walk.

Run ``python tests/_house_counts.py`` (a table), ``--json`` (one object), ``--list NAME``
(every place a count is made of, ``path:line what``); ``tests/house_counts.json`` keeps
the counts before the issue's work (and after it). What is counted, in ``common/``,
``machine/``, ``estimators/``, ``harness/`` and ``server/`` (tests and docs aside):

``event_kind_vocabularies``
    Modules that spell the vocabulary of event kinds: a tuple, list or set display, the
    keys of a dict display, a ``Literal[...]`` or a class body (an enumeration) holding
    two or more of the kinds' strings (:data:`EVENT_KINDS`). One definition imported
    everywhere counts once.
``event_kind_literals``
    Modules with any kind's string as a constant outside docstrings (a use spelled by
    hand: ``if kind == "breakage"``); reported beside the vocabularies.
``loose_dicts``
    Loose string-keyed mappings in type expressions: ``dict``/``Dict``/``Mapping``/
    ``MutableMapping`` of ``str`` to ``Any`` or ``object`` in annotations (arguments,
    returns, variables and fields), in ``cast(...)`` and in type aliases; and every use
    of an *alias* of one (a module-level ``X = dict[str, Any]``, ``X: TypeAlias = ...``,
    ``type X = ...``, or a ``TypedDict`` with an ``Any``/``object`` field) in those
    places. Renaming a loose dict does not remove it: its alias is counted at each use.
``long_positional``
    Functions taking more than :data:`MAX_POSITIONAL` positional parameters (``self``
    and ``cls`` aside).
``duplicate_concepts``
    Names of :data:`CONCEPTS` defined (a class or a module-level assignment) in more than
    one module, counted once per extra definition; and each module whose file name another
    module of its layer (a package, or a role folder of ``server/``) also has
    (``records/store.py`` and ``records/history/store.py``).
``stand_ins``
    Objects made on the spot by ``type(name, bases, dict)()`` (duck-typed stand-ins).
"""

from __future__ import annotations

import ast
import json
import sys
from collections import Counter, defaultdict
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("common", "machine", "estimators", "harness", "server")
#: the event kinds' strings: the vocabulary whose spellings are counted
EVENT_KINDS = frozenset({"breakage", "collision", "missing_tool", "wear_limit", "life_short"})
MAX_POSITIONAL = 12
#: names of one concept each, which should be defined once
CONCEPTS = ("Channel", "KnobValue", "Family", "EventKind")
_MAPPINGS = frozenset({"dict", "Dict", "Mapping", "MutableMapping"})
_LOOSE_VALUES = frozenset({"Any", "object"})
#: ``type X = ...`` (Python 3.12+; nothing to find on 3.11)
_TYPE_ALIAS: tuple[type, ...] = (ast.TypeAlias,) if hasattr(ast, "TypeAlias") else ()


@dataclass
class Found:
    """What one count is made of: ``path:line what`` per place."""

    places: dict[str, list[str]] = field(default_factory=lambda: defaultdict(list))

    def add(self, name: str, path: str, line: int, what: str) -> None:
        self.places[name].append(f"{path}:{line} {what}")


def _name(node: ast.expr) -> str | None:
    """The last name of ``x`` or ``a.b.x``."""
    if isinstance(node, ast.Name):
        return node.id
    if isinstance(node, ast.Attribute):
        return node.attr
    if isinstance(node, ast.Constant) and isinstance(node.value, str):
        return node.value  # a string annotation's name
    return None


def is_loose_mapping(node: ast.expr) -> bool:
    """``dict[str, Any]``, ``Mapping[str, object]``... (the node itself)."""
    if not isinstance(node, ast.Subscript) or _name(node.value) not in _MAPPINGS:
        return False
    args = node.slice.elts if isinstance(node.slice, ast.Tuple) else [node.slice]
    return len(args) == 2 and _name(args[0]) == "str" and _name(args[1]) in _LOOSE_VALUES


def _type_nodes(expr: ast.expr) -> Iterator[ast.expr]:
    """Every node of a type expression, a string annotation parsed."""
    for node in ast.walk(expr):
        if isinstance(node, ast.Constant) and isinstance(node.value, str):
            try:
                inner = ast.parse(node.value, mode="eval").body
            except SyntaxError:
                continue
            yield from _type_nodes(inner)
        else:
            yield node


def loose_in(expr: ast.expr, aliases: set[str]) -> list[str]:
    """The loose mappings and alias uses inside a type expression."""
    out = []
    for node in _type_nodes(expr):
        if is_loose_mapping(node):
            out.append(ast.unparse(node))
        elif isinstance(node, ast.Name | ast.Attribute) and _name(node) in aliases:
            out.append(f"alias {_name(node)}")
    return out


def _is_typeddict(node: ast.ClassDef) -> bool:
    return any(_name(b) == "TypedDict" for b in node.bases)


def _module_aliases(tree: ast.Module) -> set[str]:
    """Module-level aliases of a loose mapping, and Any-valued TypedDicts."""
    found = set()
    for node in tree.body:
        if isinstance(node, ast.Assign) and len(node.targets) == 1:
            target, value = node.targets[0], node.value
        elif isinstance(node, ast.AnnAssign) and node.value is not None:
            if _name(node.annotation) != "TypeAlias":
                continue
            target, value = node.target, node.value
        elif isinstance(node, _TYPE_ALIAS):
            target, value = node.name, node.value
        elif isinstance(node, ast.ClassDef) and _is_typeddict(node):
            fields = [s.annotation for s in node.body if isinstance(s, ast.AnnAssign)]
            if any(_name(f) in _LOOSE_VALUES for f in fields):
                found.add(node.name)
            continue
        else:
            continue
        if isinstance(target, ast.Name) and any(is_loose_mapping(n) for n in _type_nodes(value)):
            found.add(target.id)
    return found


def _annotations(tree: ast.Module) -> Iterator[tuple[int, ast.expr]]:
    """(line, type expression) of every annotation and ``cast`` target of a module."""
    for node in ast.walk(tree):
        if isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef):
            a = node.args
            for arg in [*a.posonlyargs, *a.args, *a.kwonlyargs, a.vararg, a.kwarg]:
                if arg is not None and arg.annotation is not None:
                    yield arg.lineno, arg.annotation
            if node.returns is not None:
                yield node.lineno, node.returns
        elif isinstance(node, ast.AnnAssign):
            yield node.lineno, node.annotation
        elif isinstance(node, ast.Call) and _name(node.func) == "cast" and node.args:
            yield node.lineno, node.args[0]


def _alias_definitions(tree: ast.Module) -> Iterator[tuple[int, ast.expr]]:
    """(line, value) of module-level type aliases (counted where they are defined)."""
    for node in tree.body:
        if isinstance(node, ast.Assign) and len(node.targets) == 1:
            yield node.lineno, node.value
        elif isinstance(node, ast.AnnAssign) and _name(node.annotation) == "TypeAlias":
            if node.value is not None:
                yield node.lineno, node.value
        elif isinstance(node, _TYPE_ALIAS):
            yield node.lineno, node.value


def _docstrings(tree: ast.Module) -> set[int]:
    """ids of the docstring nodes (module, classes, functions)."""
    out = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Module | ast.ClassDef | ast.FunctionDef | ast.AsyncFunctionDef):
            body = node.body
            if body and isinstance(body[0], ast.Expr) and isinstance(body[0].value, ast.Constant):
                out.add(id(body[0].value))
    return out


def _kinds_of(elts: list[ast.expr | None]) -> set[str]:
    return {
        e.value
        for e in elts
        if isinstance(e, ast.Constant) and isinstance(e.value, str) and e.value in EVENT_KINDS
    }


def _vocabulary_displays(tree: ast.Module) -> Iterator[tuple[int, set[str]]]:
    """(line, kinds) of every display or Literal holding two kinds or more."""
    for node in ast.walk(tree):
        kinds: set[str] = set()
        if isinstance(node, ast.Tuple | ast.List | ast.Set):
            kinds = _kinds_of(list(node.elts))
        elif isinstance(node, ast.Dict):
            kinds = _kinds_of(list(node.keys))
        elif isinstance(node, ast.Subscript) and _name(node.value) == "Literal":
            s = node.slice
            kinds = _kinds_of(list(s.elts) if isinstance(s, ast.Tuple) else [s])
        elif isinstance(node, ast.ClassDef):  # an enumeration: NAME = "kind" in its body
            values = [b.value for b in node.body if isinstance(b, ast.Assign)]
            kinds = _kinds_of(list(values))
        if len(kinds) >= 2:
            yield node.lineno, kinds


def _positional(node: ast.FunctionDef | ast.AsyncFunctionDef) -> int:
    names = [a.arg for a in [*node.args.posonlyargs, *node.args.args]]
    return len(names) - (1 if names and names[0] in ("self", "cls") else 0)


def modules(root: Path, packages: tuple[str, ...]) -> list[tuple[str, ast.Module]]:
    """(path relative to root, parsed tree) of every module of the packages."""
    out = []
    for pkg in packages:
        for path in sorted((root / pkg).rglob("*.py")):
            text = path.read_text(encoding="utf-8")
            out.append((path.relative_to(root).as_posix(), ast.parse(text, filename=str(path))))
    return out


def _count_kinds(found: Found, path: str, tree: ast.Module) -> None:
    seen = set()
    for line, kinds in _vocabulary_displays(tree):
        what = ", ".join(sorted(kinds))
        if (line, what) not in seen:  # a Literal's tuple is the Literal's
            seen.add((line, what))
            found.add("event_kind_vocabularies", path, line, what)
    docs = _docstrings(tree)
    for node in ast.walk(tree):
        if (
            isinstance(node, ast.Constant)
            and isinstance(node.value, str)
            and node.value in EVENT_KINDS
            and id(node) not in docs
        ):
            found.add("event_kind_literals", path, node.lineno, repr(node.value))


def _count_loose(found: Found, path: str, tree: ast.Module, aliases: set[str]) -> None:
    for line, expr in _annotations(tree):
        for what in loose_in(expr, aliases):
            found.add("loose_dicts", path, line, what)
    for line, value in _alias_definitions(tree):
        for node in _type_nodes(value):
            if is_loose_mapping(node):
                found.add("loose_dicts", path, line, f"alias of {ast.unparse(node)}")
    for node in ast.walk(tree):
        if isinstance(node, ast.ClassDef) and node.name in aliases and _is_typeddict(node):
            found.add("loose_dicts", path, node.lineno, f"Any-valued TypedDict {node.name}")


def _is_type_call(node: ast.expr) -> bool:
    """``type(name, bases, dict)``: a class made on the spot (called at once: a stand-in)."""
    return (
        isinstance(node, ast.Call)
        and isinstance(node.func, ast.Name)
        and node.func.id == "type"
        and len(node.args) == 3
    )


def _count_functions(found: Found, path: str, tree: ast.Module) -> None:
    for node in ast.walk(tree):
        if isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef):
            n = _positional(node)
            if n > MAX_POSITIONAL:
                found.add("long_positional", path, node.lineno, f"{node.name} ({n})")
        elif isinstance(node, ast.Call) and _is_type_call(node.func):
            assert isinstance(node.func, ast.Call)
            found.add("stand_ins", path, node.lineno, ast.unparse(node.func.args[0]))


def _stem_key(path: str) -> tuple[str, str]:
    """(the layer: a package, or a role folder of ``server/``; the module's file name)."""
    parts = path.split("/")
    layer = "/".join(parts[:2]) if parts[0] == "server" and len(parts) > 2 else parts[0]
    return layer, parts[-1]


def _count_concepts(found: Found, mods: list[tuple[str, ast.Module]]) -> None:
    where: dict[str, list[tuple[str, int]]] = defaultdict(list)
    for path, tree in mods:
        for node in tree.body:
            names: list[tuple[str, int]] = []
            if isinstance(node, ast.ClassDef):
                names = [(node.name, node.lineno)]
            elif isinstance(node, ast.Assign | ast.AnnAssign):
                targets = node.targets if isinstance(node, ast.Assign) else [node.target]
                names = [(t.id, node.lineno) for t in targets if isinstance(t, ast.Name)]
            for name, line in names:
                if name in CONCEPTS:
                    where[name].append((path, line))
    for name, places in sorted(where.items()):
        for path, line in places[1:]:
            found.add("duplicate_concepts", path, line, f"{name} (also {places[0][0]})")
    stems = Counter(_stem_key(p) for p, _ in mods)
    for path, _ in mods:
        key = _stem_key(path)
        if stems[key] > 1 and key[1] not in ("__init__.py", "errors.py"):
            found.add("duplicate_concepts", path, 1, f"module name {key[1]}")


def count(root: Path = ROOT, packages: tuple[str, ...] = PACKAGES) -> Found:
    """Every count's places in the tree under ``root``."""
    mods = modules(root, packages)
    aliases = set().union(*(_module_aliases(tree) for _, tree in mods)) if mods else set()
    found = Found()
    for path, tree in mods:
        _count_kinds(found, path, tree)
        _count_loose(found, path, tree, aliases)
        _count_functions(found, path, tree)
    _count_concepts(found, mods)
    return found


METRICS = (
    "event_kind_vocabularies",
    "event_kind_literals",
    "loose_dicts",
    "long_positional",
    "duplicate_concepts",
    "stand_ins",
)
#: counted by module (the rest by place)
BY_MODULE = ("event_kind_vocabularies", "event_kind_literals")


def summary(found: Found) -> dict[str, dict[str, int]]:
    """Each metric's total and its share per top-level package."""
    out: dict[str, dict[str, int]] = {}
    for metric in METRICS:
        places = found.places.get(metric, [])
        paths = [p.split(":", 1)[0] for p in places]
        if metric in BY_MODULE:
            paths = sorted(set(paths))
        per = Counter(p.split("/")[0] for p in paths)
        out[metric] = {"total": len(paths), **{pkg: per.get(pkg, 0) for pkg in PACKAGES}}
    return out


def main(argv: list[str]) -> int:
    found = count()
    if "--list" in argv:
        metric = argv[argv.index("--list") + 1]
        places = found.places.get(metric, [])
        print("\n".join(places) if places else f"(no {metric})")
        return 0
    table = summary(found)
    if "--json" in argv:
        print(json.dumps(table, indent=1))
        return 0
    print(f"{'count':26} {'total':>6} " + " ".join(f"{p:>10}" for p in PACKAGES))
    for metric, row in table.items():
        print(f"{metric:26} {row['total']:6d} " + " ".join(f"{row[p]:10d}" for p in PACKAGES))
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
