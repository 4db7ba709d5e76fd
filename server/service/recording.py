"""A recording of the live source: the loop thread hands blocks over, a writer thread
writes them (``POST /api/record``).

The loop's cost per block is one queue put of the source block's arrays (references: a
source hands out fresh arrays every step); the text formatting and the file I/O run on
the writer thread through :class:`server.records.recorder.Recorder` (temporary CSV,
sidecar and rename on close). A recording ends on request, at its size or duration
limit, at a discontinuity of the source (a gap: the log must stay uniformly sampled), at
a pipeline change (scenario, replay, reset) and at shutdown; in every case the blocks
already handed over are written before the file is renamed into place.
"""

from __future__ import annotations

import queue
import threading
from pathlib import Path
from typing import TYPE_CHECKING, Any, TypedDict

import numpy as np

from common.arrays import F64
from server.errors import CutwatchError
from server.records.recorder import Recorder, RecordingSummary

if TYPE_CHECKING:
    from server.pipeline.sources import MeasurementSource, SourceBlock

#: the unit family of every live source (the observers work on motor and load angles)
LIVE_UNITS = {"effort": "N m", "position": "rad", "current": "A"}


class RecordingSidecar(TypedDict):
    """The sidecar of a recording of the live source (docs/design.md's keys)."""

    sample_time: float  # [s]
    units: dict[str, str]  # unit family: effort, position, current
    kind: str  # the source's model kind (two_inertia...)
    nominal: dict[str, float]  # the source's nominal parameters by name
    encoder_resolution: float  # [rad]
    source: str  # where the samples came from


def source_sidecar(source: MeasurementSource, scenario: str) -> RecordingSidecar:
    """The sidecar of a recording of ``source``: docs/design.md's keys (sample time, units, kind,
    nominal, encoder resolution) and where the samples came from."""
    return {
        "sample_time": float(source.sample_time),
        "units": dict(LIVE_UNITS),
        "kind": source.kind,
        "nominal": source.nominal.as_dict(),
        "encoder_resolution": float(source.encoder_resolution),
        "source": f"cutwatch serve: {source.name} ({scenario})",
    }


def block_columns(block: SourceBlock) -> dict[str, F64]:
    """The measurements of one source block as the recorder's columns; ``f_ext`` only
    when the source gives a reference force (finite) for every sample."""
    m = block.meas
    cols: dict[str, F64] = {"t": m.t, "tau_m": m.tau_m, "i_m": m.i_m, "q_m": m.q_m, "q_l": m.q_l}
    f = np.asarray(m.f_ext)
    if f.size and bool(np.isfinite(f).all()):
        cols["f_ext"] = f
    return cols


class Recording:
    """One recording in progress: a :class:`Recorder` fed by a writer thread.

    Parameters
    ----------
    path
        The final CSV path in the recordings area.
    sidecar
        From :func:`source_sidecar`.
    max_bytes, max_seconds
        The recorder's limits.
    """

    def __init__(
        self, path: Path, sidecar: RecordingSidecar, *, max_bytes: float, max_seconds: float
    ) -> None:
        self.recorder = Recorder(path, sidecar, max_bytes=max_bytes, max_seconds=max_seconds)
        self.name = path.name
        self._q: queue.SimpleQueue[tuple[str, Any]] = queue.SimpleQueue()
        self._ending = False
        self._done = threading.Event()
        self.result: RecordingSummary | None = None
        self._thread = threading.Thread(target=self._write, name=f"record-{self.name}", daemon=True)
        self._thread.start()

    @property
    def active(self) -> bool:
        """True until the recording has been asked to end (or has ended by itself)."""
        return not self._ending and not self.recorder.limit_reason and not self._done.is_set()

    def feed(self, block: SourceBlock) -> None:
        """Hand one source block over (loop thread; never blocks). A discontinuity ends
        the recording before that block: the log stays uniformly sampled."""
        if self._ending:
            return
        if block.discontinuity is not None:
            self.end(f"source discontinuity ({block.discontinuity})")
            return
        self._q.put(("block", block_columns(block)))

    def end(self, reason: str) -> None:
        """Ask the writer to finish with ``reason`` after the blocks handed over (never
        blocks; :meth:`wait` for the result)."""
        if not self._ending:
            self._ending = True
            self._q.put(("end", reason))

    def wait(self, timeout: float = 30.0) -> RecordingSummary:
        """The recording's summary once its files are in place."""
        self._done.wait(timeout)
        return self.result if self.result is not None else self.summary()

    def summary(self) -> RecordingSummary:
        return self._listed(self.recorder.summary(), self.active)

    def _listed(self, s: RecordingSummary, active: bool) -> RecordingSummary:
        # seconds as the listing of the files computes them: samples x sample time
        s["seconds"] = s["samples"] * float(self.recorder.sidecar.get("sample_time", 0.0))
        s["active"] = active
        return s

    def _write(self) -> None:
        reason = "stopped"
        try:
            while True:
                kind, item = self._q.get()
                if kind == "end":
                    reason = str(item)
                    break
                if self.recorder.limit_reason:
                    continue  # stopped by a limit: drop the rest until the end arrives
                try:
                    self.recorder.append(item)
                except CutwatchError as exc:  # the source's columns changed
                    self._ending = True
                    reason = str(exc)
                    break
                if self.recorder.limit_reason:
                    self._ending = True
                    reason = self.recorder.limit_reason
                    break
        finally:
            self.result = self._listed(self.recorder.close(reason), False)
            self._done.set()


def default_name(now: float) -> str:
    """``rec-YYYYmmdd-HHMMSS.csv`` in UTC."""
    import time

    return time.strftime("rec-%Y%m%d-%H%M%S.csv", time.gmtime(now))
