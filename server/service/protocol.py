"""The live stream's encoding and its SCHEMA, derived from the message models.

Two message types travel from server to client as JSON text:

``hello`` (first message after connecting)
    ``{"type": "hello", "version": VERSION, "channels": [{"name", "unit", "group",
    "label", "grid"}, ...], "sample_time": s, "scenario": name, "knobs": {...}}``

``data`` (at the display rate, ~20 Hz)
    ``{"type": "data", "dropped": n, "seq": k, "wall": unix_s, "t": [...], "ts": [...],
    "ch": {name: [...]}, "health": {...}, "knobs": {...}, "accuracy": {...},
    "status": {...}}``. Two display grids: a
    channel whose ``grid`` is ``"t"`` (the forces) has one value per entry of ``t``; a
    channel on ``"ts"`` (parameters, modes, harmonics: slow signals) one per entry of
    ``ts``, a coarser subset of the same samples. ``dropped`` counts the frames this
    client lost (buffer full) since its previous frame.

``accuracy`` (issue 13): the rolling rms of every force estimate at the frame's last
sample, one small object rather than more channels (its values change slowly; the page
shows the latest numbers and keeps their history itself). Keys ``SCHEMA["accuracy"]``:
``mode`` (``"truth"``: against the true force; ``"agreement"``: a source without truth,
each estimate against the per-sample mean of the ``mean_of`` estimates), ``windows``
([1, 10] s), ``span`` (seconds each window really covers), ``rms`` ({estimate: [one value
per window]}), ``rms_q`` (against the Q(s)-filtered true force, the observers' reachable
target; empty without truth), ``floor`` (rms of Q(s)F - F; nulls without truth), each
value to 4 significant digits, null where unknown (see
:mod:`server.pipeline.accuracy`).

Identified parameters with intervals (issue 13): for each name in ``SCHEMA["intervals"]``
the stream carries the estimate, the 95 % interval's bounds and an excited flag (1: the
data determine it; 0: show it greyed, "not excited", not as a number), on the slow grid.

``event`` (issue 21: when the monitor raises an event, and again when it is acknowledged)
    ``{"type": "event", "event": {"id", "kind", "action", "t", "tool", "program",
    "line", "part", "value", "limit", "unit", "message", "machine", "acked",
    "acked_by", "acked_wall"}}``; never dropped for a slow client (frames are). A new
    client gets the unacknowledged events the service keeps right after its ``hello``.
    Every frame's ``status`` is the status strip (``SCHEMA["status"]``: state off,
    teaching, watching or alarm; tool, program, line, part, wear_share, life_left_min,
    unacked).

JSON was measured against a binary (float32) encoding: see
docs/live-service.md ("Stream protocol").

The shapes are the models of :mod:`server.service.messages`; :data:`SCHEMA` (the field
lists a client checks) is derived from them, and :func:`javascript` writes it as the
dashboard's ``web/schema.js`` (``cutwatch schema --js --out web/schema.js``, ``make
schema``); ``tests/service/test_protocol.py`` fails when that file is stale.
"""

from __future__ import annotations

import json
import math
from typing import Any

from common.jsonsafe import json_safe
from server.service.messages import MESSAGES, VERSION, Channel, Data, Hello, fields

__all__ = ["SCHEMA", "VERSION", "data_body", "hello", "javascript", "with_dropped"]
#: channel groups shown on the fast grid ``t``; every other group goes on ``ts``
FAST_GROUPS = frozenset({"force"})
#: the slow grid keeps one sample in SLOW_FACTOR of the fast one
SLOW_FACTOR = 6
#: significant digits of the ``accuracy`` numbers in a data frame
ACCURACY_DIGITS = 4


def grid_of(group: str) -> str:
    """``"t"`` for the fast display grid, ``"ts"`` for the slow one."""
    return "t" if group in FAST_GROUPS else "ts"


#: identified parameter -> its channels: estimate, 95 % bounds, excited flag (0/1)
INTERVALS: dict[str, dict[str, str]] = {
    q: {"estimate": f"{q}_seg", "lower": f"{q}_lo", "upper": f"{q}_hi", "excited": f"{q}_excited"}
    for q in ("J_L", "B_L", "F_CL")
}

SCHEMA: dict[str, Any] = {
    "version": VERSION,
    **{name: fields(model) for name, model in MESSAGES.items()},
    "fast_groups": sorted(FAST_GROUPS),
    "intervals": INTERVALS,
    "versions": {name: model.VERSION for name, model in MESSAGES.items()},
}
#: the fields of a frame that :func:`data_body` encodes (``type`` and ``dropped``: per client)
_BODY_FIELDS = tuple(f for f in fields(Data) if f not in ("type", "dropped"))


def hello(
    channels: list[dict[str, str]], sample_time: float, scenario: str, knobs: dict[str, Any]
) -> str:
    """Encode the ``hello`` message (checked against :class:`~server.service.messages.Hello`)."""
    msg = Hello(
        channels=[Channel.model_validate(c) for c in channels],
        sample_time=sample_time,
        scenario=scenario,
        knobs=json_safe(knobs),
    )
    return json.dumps(json_safe(msg.model_dump()), allow_nan=False)


def data_body(
    seq: int,
    wall: float,
    t: list[float | None],
    ts: list[float | None],
    ch: dict[str, list[float | None]],
    health: dict[str, Any],
    knobs: dict[str, Any],
    accuracy: dict[str, Any],
    status: dict[str, Any] | None = None,
) -> str:
    """Encode a data frame without its per-client ``dropped`` field (done once per frame).

    ``t``, ``ts`` and ``ch`` must already be JSON-safe lists (see :func:`samples`);
    ``accuracy`` the pipeline's summary, JSON-safe (rounded to :data:`ACCURACY_DIGITS`);
    ``status`` the monitor's status (a :class:`~server.service.messages.MonitorStatus`
    dict, JSON-safe; None: not known).

    :func:`with_dropped` completes it per client.
    """
    # the fields by their names in Data, unvalidated (a frame is large and frequent; the
    # tests validate real frames against Data); in Data's order, without type and dropped
    frame = Data.model_construct(
        seq=seq,
        wall=wall,
        t=t,
        ts=ts,
        ch=ch,
        health=json_safe(health),
        knobs=json_safe(knobs),
        accuracy=accuracy,
        status=status,
    )
    body = {f: getattr(frame, f) for f in _BODY_FIELDS}
    return json.dumps(body, allow_nan=False, separators=(",", ":"))


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
    """The dashboard's schema module (``web/schema.js``): the stream's version, its fast
    groups, the interval channels and :data:`SCHEMA`, as ES module exports."""

    def const(name: str, value: object) -> str:
        return f"export const {name} = {json.dumps(value, indent=2)};\n"

    return "\n".join(
        [
            _JS_HEADER,
            const("VERSION", VERSION),
            "// channel groups on the fast grid t; every other group is on ts",
            const("FAST_GROUPS", sorted(FAST_GROUPS)),
            "// identified parameter -> its channels: estimate, 95 % bounds, excited flag (1/0;",
            '// 0: show the parameter greyed, "not excited", not as a number)',
            const("INTERVALS", INTERVALS),
            "// the fields of each message, and each message shape's version",
            _js_schema(),
        ]
    )


def _js_schema() -> str:
    """``SCHEMA`` as JS, its version, fast groups and intervals by the constants' names."""
    refs = {"version": "VERSION", "fast_groups": "FAST_GROUPS", "intervals": "INTERVALS"}
    rest = json.dumps({k: v for k, v in SCHEMA.items() if k not in refs}, indent=2)
    named = "".join(f',\n  "{key}": {name}' for key, name in refs.items())
    return f"export const SCHEMA = {rest[:-2]}{named}\n}};\n"
