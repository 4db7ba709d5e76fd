"""Saving and restoring estimator state: one file, a JSON header and the arrays (npz).

The format (docs/checkpoints.md):

- a NumPy ``.npz`` archive (uncompressed); each array of the state is one member,
  ``a0``, ``a1``...;
- the member ``header``: UTF-8 JSON (as uint8) with ``format`` (:data:`FORMAT`),
  ``format_version`` (:data:`FORMAT_VERSION`, the codec's), ``kind`` and ``version`` (what
  the state is and the version of its schema, given by the writer: a reader refuses
  another kind or version), ``meta`` (free JSON: time, scenario...) and ``tree``.
- ``tree`` describes the state: JSON ``null``, booleans, integers and strings as
  themselves; a float as ``{"f": float.hex(x)}`` (exact, NaN and infinities included);
  ``{"a": "a3"}`` an array member (dtype and shape kept; a NumPy scalar is a 0-d member
  with ``"s": true``); ``{"tuple": [...]}``, ``{"list": [...]}``, ``{"frozenset": [...]}``,
  ``{"dict": {...}}`` (string keys), ``{"items": [[key, value], ...]}`` (other keys);
  ``{"rng": state}`` a NumPy Generator (its bit generator's state);
  ``{"obj": "module:Qualname", "fields": {...}}`` a dataclass or plain object of
  cutwatch's own packages (:data:`PACKAGES`): its fields (a dataclass's, every one) or
  its instance attributes, restored onto a new instance without calling ``__init__``.

No code is loaded from a file: only classes of :data:`PACKAGES` already importable are
named, and any other value is refused with :class:`StateFormatError`.
"""

from __future__ import annotations

import dataclasses
import importlib
import io
import json
import os
from collections.abc import Mapping
from typing import Any, NotRequired, TypeAlias, TypedDict

import numpy as np

#: the format's name in every header
FORMAT = "cutwatch-state"
#: version of the codec (the tree's encoding); a file of another version is refused
FORMAT_VERSION = 1
#: packages whose classes a state may name
PACKAGES = ("common.", "machine.", "estimators.", "harness.", "server.pipeline.")
#: modules moved since a state could name them: a state written before reads as now
MOVED = {
    **{
        f"server.pipeline.{m}": f"harness.{m}"
        for m in ("accuracy", "eccentricity_loop", "shards", "wear_clock")
    },
    "machine.params": "machine.stage_params",  # the stage's parameters, named by meaning
    # estimators/ grouped by topic (issue 34 item 4): the tool-wear models
    **{
        f"estimators.{old}": f"estimators.wear.{new}"
        for old, new in (
            ("wear_calibration", "calibration"),
            ("wear_hybrid", "hybrid"),
            ("wear_law", "law"),
            ("wear_linear", "linear"),
            ("wear_monitor", "monitor"),
            ("wear_observer", "observer"),
            ("turning_wear", "turning"),
            ("centre_wear", "centre"),
        )
    },
    # ... and the residual loop (no live state holds one of its classes today; mapped all
    # the same, so that nothing written by a later part can be lost to the move)
    "estimators.residual": "estimators.residual.rigid",
    **{
        f"estimators.residual_{m}": f"estimators.residual.{m}"
        for m in ("cv", "engine", "families", "rate", "selection", "shapes", "two_inertia")
    },
    # ... and the process monitors (the live process and spindle parts checkpoint them)
    "estimators.process_monitor": "estimators.monitoring.process",
    "estimators.spindle_power": "estimators.monitoring.spindle_power",
    # ... and the stability lobes (no live state holds them today; mapped all the same)
    "estimators.lobes": "estimators.chatter.lobes",
    "estimators.lobes_sd": "estimators.chatter.sd",
    "estimators.lobes_zoa": "estimators.chatter.zoa",
}


class StateFormatError(ValueError):
    """A state file cannot be read as the state asked for: not a state file, another
    kind, another version, or a value the codec does not know. The message names the
    file, what was expected and what was found."""


#: a node of the header's tree as JSON holds it
JsonNode: TypeAlias = "bool | int | float | str | list[JsonNode] | dict[str, JsonNode] | None"


class ArrayNode(TypedDict):
    """An array (``s``: a NumPy scalar) kept in the file's member ``a``."""

    a: str
    s: NotRequired[bool]


class ObjNode(TypedDict):
    """An object of a cutwatch class (``module:qualname``) and its fields' nodes."""

    obj: str
    fields: dict[str, JsonNode]


class _Encoder:
    def __init__(self) -> None:
        self.arrays: dict[str, np.ndarray] = {}

    def array(self, a: np.ndarray, scalar: bool = False) -> ArrayNode:
        key = f"a{len(self.arrays)}"
        if a.dtype == object:
            raise StateFormatError(f"state: expected numeric arrays, found dtype object at {key}")
        self.arrays[key] = np.array(a, copy=True)
        return {"a": key, "s": True} if scalar else {"a": key}

    def node(self, x: Any, where: str) -> Any:
        if x is None or isinstance(x, bool | str):
            return x
        if isinstance(x, int) and not isinstance(x, bool):
            return int(x)
        if isinstance(x, float):
            return {"f": float(x).hex()}
        if isinstance(x, np.ndarray):
            return self.array(x)
        if isinstance(x, np.generic):
            return self.array(np.asarray(x), scalar=True)
        if isinstance(x, np.random.Generator):
            return {"rng": x.bit_generator.state}
        if isinstance(x, tuple):
            return {"tuple": [self.node(v, f"{where}[{i}]") for i, v in enumerate(x)]}
        if isinstance(x, frozenset):
            items = sorted(x, key=repr)
            return {"frozenset": [self.node(v, f"{where}{{}}") for v in items]}
        if isinstance(x, list):
            return {"list": [self.node(v, f"{where}[{i}]") for i, v in enumerate(x)]}
        if isinstance(x, dict):
            if all(isinstance(k, str) for k in x):
                return {"dict": {k: self.node(v, f"{where}.{k}") for k, v in x.items()}}
            return {
                "items": [
                    [self.node(k, f"{where}.key"), self.node(v, f"{where}[{k!r}]")]
                    for k, v in x.items()
                ]
            }
        return self.obj(x, where)

    def obj(self, x: Any, where: str) -> ObjNode:
        cls = type(x)
        name = f"{cls.__module__}:{cls.__qualname__}"
        if not cls.__module__.startswith(PACKAGES):
            raise StateFormatError(
                f"state: {where}: expected a value of cutwatch's packages {PACKAGES}, found {name}"
            )
        if dataclasses.is_dataclass(x):
            names = [f.name for f in dataclasses.fields(x)]
        else:
            names = list(vars(x))
        fields = {k: self.node(getattr(x, k), f"{where}.{k}") for k in names}
        return {"obj": name, "fields": fields}


def _class(name: str, where: str) -> type:
    module, _, qual = name.partition(":")
    module = MOVED.get(module, module)
    if not module.startswith(PACKAGES):
        raise StateFormatError(f"state: {where}: class {name} is outside {PACKAGES}")
    try:
        obj: Any = importlib.import_module(module)
        for part in qual.split("."):
            obj = getattr(obj, part)
    except (ImportError, AttributeError):
        raise StateFormatError(f"state: {where}: class {name} no longer exists") from None
    if not isinstance(obj, type):
        raise StateFormatError(f"state: {where}: {name} is not a class")
    return obj


def _decode(node: Any, arrays: Mapping[str, np.ndarray], where: str) -> Any:
    if node is None or isinstance(node, bool | int | str):
        return node
    if isinstance(node, dict) and len(node) >= 1:
        if "f" in node:
            return float.fromhex(node["f"])
        if "a" in node:
            if node["a"] not in arrays:
                raise StateFormatError(f"state: {where}: array member {node['a']} missing")
            a = np.array(arrays[node["a"]], copy=True)
            return a[()] if node.get("s") else a
        if "rng" in node:
            g = np.random.default_rng()
            g.bit_generator.state = node["rng"]
            return g
        if "tuple" in node:
            return tuple(_decode(v, arrays, f"{where}[{i}]") for i, v in enumerate(node["tuple"]))
        if "frozenset" in node:
            return frozenset(_decode(v, arrays, f"{where}{{}}") for v in node["frozenset"])
        if "list" in node:
            return [_decode(v, arrays, f"{where}[{i}]") for i, v in enumerate(node["list"])]
        if "dict" in node:
            return {k: _decode(v, arrays, f"{where}.{k}") for k, v in node["dict"].items()}
        if "items" in node:
            return {
                _hashable(_decode(k, arrays, f"{where}.key")): _decode(v, arrays, f"{where}[]")
                for k, v in node["items"]
            }
        if "obj" in node:
            return _decode_obj(node, arrays, where)
    raise StateFormatError(f"state: {where}: unknown node {str(node)[:60]!r}")


def _hashable(k: Any) -> Any:
    """A decoded key as a dict key (a NumPy scalar as its Python value)."""
    return k.item() if isinstance(k, np.generic) else k


def _decode_obj(node: Mapping[str, Any], arrays: Mapping[str, np.ndarray], where: str) -> Any:
    cls = _class(str(node["obj"]), where)
    fields = node["fields"]
    if dataclasses.is_dataclass(cls):
        want = {f.name for f in dataclasses.fields(cls)}
        if set(fields) != want:
            raise StateFormatError(
                f"state: {where}: {node['obj']} has fields {sorted(want)}, the file gives "
                f"{sorted(fields)}"
            )
    x: Any = object.__new__(cls)
    for k, v in fields.items():
        object.__setattr__(x, k, _decode(v, arrays, f"{where}.{k}"))
    return x


def encode(state: Any) -> tuple[Any, dict[str, np.ndarray]]:
    """The tree and the arrays of ``state`` (see the module docstring).

    Raises
    ------
    StateFormatError
        A value the codec does not know (a function, a lock, a class of another
        package...), named by its path in the state.
    """
    enc = _Encoder()
    tree = enc.node(state, "state")
    return tree, enc.arrays


def decode(tree: Any, arrays: Mapping[str, np.ndarray]) -> Any:
    """The state of a tree and its arrays (the inverse of :func:`encode`).

    Raises
    ------
    StateFormatError
        An unknown node, a missing array, a class that no longer exists or whose fields
        changed.
    """
    return _decode(tree, arrays, "state")


def save_state(
    path: str | os.PathLike[str],
    state: Any,
    *,
    kind: str,
    version: int,
    meta: Mapping[str, JsonNode] | None = None,
) -> None:
    """Write ``state`` to ``path`` atomically (a temporary file renamed over it).

    Raises
    ------
    StateFormatError
        The state holds a value the codec does not know.
    """
    tree, arrays = encode(state)
    header = {
        "format": FORMAT,
        "format_version": FORMAT_VERSION,
        "kind": kind,
        "version": int(version),
        "meta": dict(meta or {}),
        "tree": tree,
    }
    buf = io.BytesIO()
    raw = json.dumps(header, allow_nan=False).encode()
    members: dict[str, Any] = {"header": np.frombuffer(raw, dtype=np.uint8), **arrays}
    np.savez(buf, **members)
    tmp = f"{os.fspath(path)}.tmp"
    with open(tmp, "wb") as f:
        f.write(buf.getvalue())
        f.flush()
        os.fsync(f.fileno())
    os.replace(tmp, path)


def read_header(path: str | os.PathLike[str]) -> dict[str, Any]:
    """The header of a state file (without decoding the state).

    Raises
    ------
    StateFormatError
        Not a state file of this codec.
    """
    try:
        with np.load(path, allow_pickle=False) as z:
            header = json.loads(bytes(z["header"]).decode())
    except (OSError, ValueError, KeyError) as exc:
        raise StateFormatError(f"{path}: expected a {FORMAT} file, found: {exc}") from None
    if not isinstance(header, dict) or header.get("format") != FORMAT:
        raise StateFormatError(f"{path}: expected a {FORMAT} file, found another npz")
    if header.get("format_version") != FORMAT_VERSION:
        raise StateFormatError(
            f"{path}: expected format_version {FORMAT_VERSION}, found "
            f"{header.get('format_version')!r}"
        )
    return header


def load_state(
    path: str | os.PathLike[str], *, kind: str, version: int
) -> tuple[Any, dict[str, Any]]:
    """The state written by :func:`save_state` and its ``meta``.

    Raises
    ------
    StateFormatError
        Not a state file, another ``kind`` or ``version`` than expected, or a state the
        code of now cannot rebuild; the message names the file, the expected and the
        found.
    FileNotFoundError
        No file at ``path``.
    """
    if not os.path.exists(path):
        raise FileNotFoundError(path)
    header = read_header(path)
    if header.get("kind") != kind:
        raise StateFormatError(f"{path}: expected kind {kind!r}, found {header.get('kind')!r}")
    if header.get("version") != version:
        raise StateFormatError(
            f"{path}: expected {kind} version {version}, found {header.get('version')!r}"
        )
    with np.load(path, allow_pickle=False) as z:
        arrays = {k: z[k] for k in z.files if k != "header"}
    try:
        state = decode(header["tree"], arrays)
    except StateFormatError as exc:
        raise StateFormatError(f"{path}: {exc}") from None
    meta = header.get("meta") or {}
    return state, meta


__all__ = [
    "FORMAT",
    "FORMAT_VERSION",
    "PACKAGES",
    "StateFormatError",
    "decode",
    "encode",
    "load_state",
    "read_header",
    "save_state",
]
