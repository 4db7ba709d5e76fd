"""The live stream's encoding and its SCHEMA, derived from the message models.

Three message types travel from server to client as JSON text, each encoded through its
model of :mod:`server.service.messages` (validated, then serialised by it):

``hello`` (first message after connecting, and again whenever the pipeline changes)
    ``{"type": "hello", "version": VERSION, "channels": [...], "charts": [...],
    "parts": [...], "sample_time": s, "scenario": name, "knobs": {...}}`` (``sample_time``
    null while a live feed has not sent its meta; the meta brings a new hello). The stream
    describes itself: each channel says the chart it is drawn on (``chart``, ``page``,
    ``order``), whether it is the simulator's truth, how it is drawn (``color``,
    ``dash``, ``width``, ``axis``), its 95 % interval's channels (``interval``), a
    shaded area (``fill_to``) and its ``role`` in the residual loop's panel; each chart
    its title, page, order, window and whether it is wide or shows the events; each part
    whether it runs and why not. The dashboard builds its charts from it
    (``web/charts.js``); no channel's name is written in ``web/``.

``data`` (at the display rate, ~20 Hz)
    ``{"type": "data", "dropped": n, "seq": k, "wall": unix_s, "t": [...], "ts": [...],
    "ch": {name: [...]}, "health": {...}, "knobs": {...}, "accuracy": {...},
    "status": {...}, "parts": [...]}``. Two display grids: a channel whose ``grid`` is
    ``"t"`` (the forces) has one value per entry of ``t``; a channel on ``"ts"``
    (parameters, modes, harmonics: slow signals) one per entry of ``ts``, a coarser
    subset of the same samples. ``dropped`` counts the frames this client lost (buffer
    full) since its previous frame.

``accuracy`` (issue 13): the rolling rms of every force estimate at the frame's last
sample, one small object rather than more channels (its values change slowly; the page
shows the latest numbers and keeps their history itself). Keys ``SCHEMA["accuracy"]``:
``mode`` (``"truth"``: against the true force; ``"measured_force"``: against the force
the machine measures, ``f_ext``; ``"none"``: no reference, nothing scored, ``reason``
says so), ``against`` (the mode, null for none), ``reason``, ``windows``
([1, 10] s), ``span`` (seconds each window really covers), ``rms`` ({estimate: [one value
per window]}), ``rms_q`` (against the Q(s)-filtered true force, the observers' reachable
target; empty without truth), ``floor`` (rms of Q(s)F - F; nulls without truth), each
value to 4 significant digits, null where unknown (see
:mod:`harness.accuracy`).

``event`` (issue 21: when the monitor raises an event, and again when it is acknowledged)
    ``{"type": "event", "event": {"id", "kind", "action", "t", "tool", "program",
    "line", "part", "value", "limit", "unit", "message", "machine", "acked",
    "acked_by", "acked_wall"}}``; never dropped for a slow client (frames are). A new
    client gets the unacknowledged events the service keeps right after its ``hello``.
    Every frame's ``status`` is the status strip (``SCHEMA["status"]``: state off,
    teaching, watching or alarm; tool, program, line, part; wear_share, life_left_min of
    one tool, wear_tool, whose it is, wear_of, its limit wear_limit_mm and the alarm's
    share of it wear_alarm_share; unacked).

JSON was measured against a binary (float32) encoding: see
docs/live-service.md ("Stream protocol"). Encoding a frame through its model (validation
and pydantic's serialiser) was measured at 156 us against 346 us for the unvalidated
``json.dumps`` it replaced (69 channels, 40 samples).

:data:`SCHEMA` (the field lists a client checks) is derived from the models, and
:func:`javascript` writes it, with each message's JSDoc type, as the dashboard's
``web/schema.js`` (``cutwatch schema --js --out web/schema.js``, ``make schema``);
``tests/service/test_protocol.py`` fails when that file is stale.
"""

from __future__ import annotations

import json
import math
from collections.abc import Mapping, Sequence
from typing import Any

from common.jsonsafe import json_safe
from server.pipeline.knobs import KnobValue
from server.pipeline.part import Channel, Chart, PartInfo
from server.records.monitor_events import EventRecord
from server.service.messages import MESSAGES, VERSION, Data, EventMessage, Hello, fields

__all__ = [
    "SCHEMA",
    "VERSION",
    "data_body",
    "event_body",
    "hello",
    "javascript",
    "with_dropped",
]
#: the slow grid keeps one sample in SLOW_FACTOR of the fast one
SLOW_FACTOR = 6
#: significant digits of the ``accuracy`` numbers in a data frame
ACCURACY_DIGITS = 4

SCHEMA: dict[str, int | list[str] | dict[str, int]] = {
    "version": VERSION,
    **{name: fields(model) for name, model in MESSAGES.items()},
    "versions": {name: model.VERSION for name, model in MESSAGES.items()},
}
#: a frame's fields but those :func:`with_dropped` adds per client
_PER_CLIENT = {"type", "dropped"}


def hello(
    channels: Sequence[Channel],
    charts: Sequence[Chart],
    parts: Sequence[PartInfo],
    sample_time: float | None,
    scenario: str,
    knobs: Mapping[str, KnobValue],
) -> str:
    """Encode the ``hello`` message through :class:`~server.service.messages.Hello`: the
    channels and charts as the parts declare them (each its ``describe()``)."""
    msg = Hello.model_validate(
        {
            "channels": [c.describe() for c in channels],
            "charts": [c.describe() for c in charts],
            "parts": parts,
            "sample_time": sample_time,
            "scenario": scenario,
            "knobs": json_safe(dict(knobs)),
        }
    )
    return msg.model_dump_json()


def data_body(frame: Mapping[str, Any]) -> str:
    """Encode a data frame through :class:`~server.service.messages.Data`, without its
    per-client ``dropped`` field (done once per frame; :func:`with_dropped` completes it).

    ``frame``: the fields of :class:`Data` by name (``seq``, ``wall``, ``t``, ``ts``,
    ``ch``, ``health``, ``knobs``, ``accuracy``, ``status``, ``parts``); the samples
    already JSON-safe lists (:func:`samples`).

    Raises
    ------
    pydantic.ValidationError
        A field missing or of the wrong shape (named).
    """
    return Data.model_validate(frame).model_dump_json(exclude=_PER_CLIENT)


def event_body(record: EventRecord) -> str:
    """Encode the ``event`` message of an event record through
    :class:`~server.service.messages.EventMessage`."""
    return EventMessage.model_validate({"event": json_safe(dict(record))}).model_dump_json()


def samples(a: Any, digits: int | None = None) -> list[float | None]:
    """A float array as a JSON-safe list (non-finite values become ``None``).

    ``digits``: round to that many significant digits relative to the array's largest
    magnitude (display precision; halves the frame size against full float64 reprs).
    """
    import numpy as np

    arr = np.asarray(a, dtype=np.float64)
    if digits is not None and arr.size:
        with np.errstate(invalid="ignore"):
            m = float(np.nanmax(np.abs(arr))) if not np.isnan(arr).all() else 0.0
        if math.isfinite(m) and m > 0.0:
            arr = np.round(arr, digits - 1 - math.floor(math.log10(m)))
    if np.isfinite(arr).all():
        out: list[float | None] = arr.tolist()
        return out
    return [float(v) if math.isfinite(v) else None for v in arr.tolist()]


def samples_rows(a: Any, digits: int) -> list[list[float | None]]:
    """:func:`samples` of every row of a 2-D array at once (same values, one pass).

    Each row is rounded to ``digits`` significant digits relative to its own largest
    magnitude, with numpy's ``round`` arithmetic (scale, ``rint``, unscale), so the result
    equals ``[samples(row, digits) for row in a]``.
    """
    import numpy as np

    arr = np.array(a, dtype=np.float64, ndmin=2)
    if arr.size == 0:
        return [[] for _ in range(arr.shape[0])]
    with np.errstate(invalid="ignore", divide="ignore"):
        finite = np.isfinite(arr)
        # like samples: NaN ignored, an infinite value leaves the row unrounded
        m = np.max(np.where(np.isnan(arr), 0.0, np.abs(arr)), axis=1)
        ok = np.isfinite(m) & (m > 0.0)
        dec = np.zeros(arr.shape[0], dtype=np.int64)
        dec[ok] = digits - 1 - np.floor(np.log10(m[ok])).astype(np.int64)
        f = np.power(10.0, np.abs(dec)).astype(np.float64)[:, None]
        pos = (dec >= 0)[:, None]
        up = np.where(pos, arr * f, arr / f)
        r = np.rint(up)
        arr = np.where(ok[:, None], np.where(pos, r / f, r * f), arr)
    out: list[list[float | None]] = []
    all_finite: list[bool] = np.all(finite, axis=1).tolist()
    for row, fin in zip(arr.tolist(), all_finite, strict=True):
        out.append(row if fin else [v if math.isfinite(v) else None for v in row])
    return out


def with_dropped(body: str, dropped: int) -> str:
    """Complete a frame body from :func:`data_body` with this client's ``dropped`` count."""
    return '{"type":"data","dropped":' + str(int(dropped)) + "," + body[1:]


_JS_HEADER = """\
// GENERATED by `cutwatch schema --js --out web/schema.js` (make schema) from the models
// in server/service/messages.py and server/service/protocol.py. Do not edit by hand:
// tests/service/test_protocol.py fails when this file differs from what the command writes.
"""


def javascript() -> str:
    """The dashboard's schema module (``web/schema.js``): the stream's version and
    :data:`SCHEMA` as ES module exports, and every message's JSDoc type (a typedef per
    model, from its JSON schema)."""

    def const(name: str, value: object) -> str:
        return f"export const {name} = {json.dumps(value, indent=2)};\n"

    return "\n".join(
        [
            _JS_HEADER,
            const("VERSION", VERSION),
            "// the fields of each message, and each message shape's version",
            const("SCHEMA", SCHEMA),
            "// the messages' types",
            *_typedefs(),
        ]
    )


def _typedefs() -> list[str]:
    """A JSDoc ``@typedef`` per message model (those it refers to included), by name."""
    out: dict[str, str] = {}
    for model in MESSAGES.values():
        schema = model.model_json_schema()
        for name, sub in {**schema.get("$defs", {}), model.__name__: schema}.items():
            if name not in out:
                out[name] = _typedef(name, sub)
    return [out[k] for k in sorted(out)]


def _typedef(name: str, schema: dict[str, Any]) -> str:
    kind = _js_type(schema) if "enum" in schema else "Object"  # an enumeration: its values
    lines = [
        f"/**\n * {_one_line(schema.get('description', name))}",
        f" * @typedef {{{kind}}} {name}",
    ]
    required = set(schema.get("required", []))
    for field, sub in schema.get("properties", {}).items():
        opt = field if field in required else f"[{field}]"
        doc = sub.get("description", "")
        lines.append(
            f" * @property {{{_js_type(sub)}}} {opt}" + (f" - {_one_line(doc)}" if doc else "")
        )
    return "\n".join(lines) + "\n */\n"


def _one_line(text: str) -> str:
    return " ".join(str(text).split())


def _js_type(s: dict[str, Any]) -> str:
    """A JSON schema's type as a JSDoc type."""
    if "$ref" in s:
        return str(s["$ref"]).rsplit("/", 1)[-1]
    if "anyOf" in s:
        return "(" + "|".join(_js_type(x) for x in s["anyOf"]) + ")"
    if "const" in s:
        return json.dumps(s["const"])
    if "enum" in s:
        return "(" + "|".join(json.dumps(v) for v in s["enum"]) + ")"
    t = s.get("type")
    if t == "array":
        return f"Array<{_js_type(s.get('items', {}))}>"
    if t == "object":
        extra = s.get("additionalProperties")
        return f"Object<string, {_js_type(extra)}>" if isinstance(extra, dict) else "Object"
    return {
        "string": "string",
        "number": "number",
        "integer": "number",
        "boolean": "boolean",
        "null": "null",
    }.get(str(t), "*")
