"""Rolling accuracy of the live force estimates (issue 13, item 4).

Over the last ``windows`` seconds (1 s and 10 s by default), per force estimate:

- with a source that has the truth (the simulator): the rms of the estimate minus the
  true cutting force, and minus the Q(s)-filtered true force (the same discrete filter as
  the observer's, :func:`estimators.filters.lowpass` of its ``q_hz``/``q_order``;
  :class:`~server.pipeline.stage_run.StageRun` builds it as ``f_ideal``). The second is
  what an observer with this Q can reach; the rms of Q(s) F - F itself is given as the
  ``floor`` (the Q filter's own error against the truth).
- with a source without truth that measures the force (a replayed log or a live feed
  with an ``f_ext`` column, issue 30 item 6): the rms of each estimate minus the measured
  force (mode ``measured_force``);
- with neither: nothing is scored (mode ``none``, with the reason). Ranking the estimates
  against their own mean (what this panel did before) ranks them backwards when most of
  them share an error, so it is not done.

Cost: per block, one vectorised pass over the block's samples gives each row's sum of
squares and its count of finite values; those per-block sums go into a ring of blocks.
A window's rms sums the newest blocks that cover it (at block resolution: with 50 ms
blocks a 1 s window is 20 whole blocks), so nothing is done per sample in Python and a
summary costs a few microseconds whatever the window.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from typing import TypedDict

import numpy as np

from common.arrays import F64

#: seconds of the rolling windows
WINDOWS = (1.0, 10.0)

#: what the estimates are scored against: the simulator's truth, a measured force, nothing
REFERENCES = ("truth", "measured_force", "none")

#: the reason given when there is no reference
NO_REFERENCE = (
    "no reference force: the source has no truth and measures no force (f_ext); the "
    "estimates are not scored against each other"
)


class AccuracySummary(TypedDict):
    """:meth:`RollingAccuracy.summary`: per window [s], each estimate's rms [N m] (NaN, or
    None once rounded: not known)."""

    mode: str
    against: str | None
    reason: str
    windows: list[float]
    span: list[float | None]
    rms: dict[str, list[float | None]]
    rms_q: dict[str, list[float | None]]
    floor: list[float | None]


class RollingAccuracy:
    """Rolling rms of each force estimate, against the truth or a measured force.

    Parameters
    ----------
    names
        The force estimates' channel names, in display order.
    sample_time
        [s].
    reference
        ``truth``: the source knows the true force: rms against it and against its Q(s)
        filtering; ``measured_force``: rms against the measured force (``f_ext``);
        ``none``: nothing to score against (every rms NaN).
    windows
        Window lengths [s], ascending.
    """

    def __init__(
        self,
        names: Sequence[str],
        sample_time: float,
        reference: str,
        windows: Sequence[float] = WINDOWS,
    ) -> None:
        if reference not in REFERENCES:
            raise ValueError(f"reference: expected one of {REFERENCES}, found {reference!r}")
        self.names = tuple(names)
        self.reference = reference
        self.has_truth = reference == "truth"
        self.windows = tuple(float(w) for w in windows)
        self.sample_time = float(sample_time)
        self._win_n = np.array([max(1, round(w / sample_time)) for w in self.windows])
        k = len(self.names)
        # rows: each estimate vs the truth, vs Q(s) truth, and Q(s) truth vs truth; or
        # each estimate vs the measured force
        self._rows = 2 * k + 1 if self.has_truth else k
        nw = len(self.windows)
        self._cap = 64
        self._s = np.zeros((self._cap, self._rows))  # sum of squares per block and row
        self._c = np.zeros((self._cap, self._rows))  # finite samples per block and row
        self._n = np.zeros(self._cap, dtype=np.int64)  # samples per block
        self._pos = 0  # next row of the ring to write
        self._len = 0  # blocks held
        # per window: running sums over its blocks, the samples they hold, its oldest block
        self._tot_s = np.zeros((nw, self._rows))
        self._tot_c = np.zeros((nw, self._rows))
        self._tot_n = np.zeros(nw, dtype=np.int64)
        self._first = np.zeros(nw, dtype=np.int64)

    def update(
        self,
        estimates: Mapping[str, F64],
        f_true: F64 | None = None,
        f_ideal: F64 | None = None,
        measured: F64 | None = None,
    ) -> None:
        """Add one block: ``estimates`` holds each name's samples; ``f_true`` and
        ``f_ideal`` (Q(s) applied to the true force) when the source has the truth;
        ``measured``: the measured force (mode ``measured_force``; NaN samples do not
        count). Mode ``none``: nothing to add."""
        if self.reference == "none" or not self.names:
            return
        e = np.vstack([estimates[k] for k in self.names])
        n = e.shape[1]
        if n == 0:
            return
        k = len(self.names)
        if self.has_truth:
            if f_true is None or f_ideal is None:
                raise ValueError("a source with the truth needs f_true and f_ideal")
            d = np.empty((self._rows, n))
            np.subtract(e, f_true, out=d[:k])
            np.subtract(e, f_ideal, out=d[k : 2 * k])
            np.subtract(f_ideal, f_true, out=d[-1])
        else:
            if measured is None:
                raise ValueError("a measured-force reference needs the measured force")
            d = e - measured
        s = np.einsum("ij,ij->i", d, d)
        if np.isfinite(s).all():  # the usual case: every sample counts
            c = np.full(self._rows, float(n))
        else:  # NaN (no reference, an observer restarting): count the finite ones
            fin = np.isfinite(d)
            s = np.einsum("ij,ij->i", np.where(fin, d, 0.0), np.where(fin, d, 0.0))
            c = fin.sum(axis=1).astype(np.float64)
        self._push(n, s, c)

    def _push(self, n: int, s: F64, c: F64) -> None:
        if self._len == self._cap and self._first[-1] == self._pos:
            self._grow()  # the oldest block is still inside the longest window
        if self._len == self._cap:  # the oldest block, outside every window, is overwritten
            self._len -= 1
        i = self._pos
        self._s[i], self._c[i], self._n[i] = s, c, n
        self._pos = (i + 1) % self._cap
        self._len += 1
        if self._pos == 0:  # once per turn of the ring: sums again, no drift
            self._resum()
            return
        self._tot_s += s
        self._tot_c += c
        self._tot_n += n
        # each window keeps the fewest newest blocks that cover it
        for j, w in enumerate(self._win_n):
            f = int(self._first[j])
            while self._tot_n[j] - self._n[f] >= w:
                self._tot_s[j] -= self._s[f]
                self._tot_c[j] -= self._c[f]
                self._tot_n[j] -= self._n[f]
                f = (f + 1) % self._cap
            self._first[j] = f

    def _resum(self) -> None:
        """The windows' sums and first blocks from the ring itself."""
        idx = (self._pos - 1 - np.arange(self._len)) % self._cap  # newest first
        cum = np.cumsum(self._n[idx])
        for j, w in enumerate(self._win_n):
            m = min(int(np.searchsorted(cum, w)) + 1, self._len)
            self._tot_s[j] = self._s[idx[:m]].sum(axis=0)
            self._tot_c[j] = self._c[idx[:m]].sum(axis=0)
            self._tot_n[j] = cum[m - 1]
            self._first[j] = idx[m - 1]

    def _grow(self) -> None:
        old = self._cap
        idx = (self._pos + np.arange(old)) % old  # oldest first (the ring is full)
        cap = 2 * old
        s, c, n = np.zeros((cap, self._rows)), np.zeros((cap, self._rows)), np.zeros(cap, np.int64)
        s[:old], c[:old], n[:old] = self._s[idx], self._c[idx], self._n[idx]
        self._first = (self._first - self._pos) % old
        self._s, self._c, self._n, self._cap = s, c, n, cap
        self._pos = old

    def rms(self) -> tuple[F64, F64]:
        """``(rms, span)``: rms per row (rows as in the constructor) and window, shape
        ``(rows, windows)``, NaN where no finite sample; and the seconds each window
        really covers (less than the window at the start)."""
        c = self._tot_c.T
        with np.errstate(invalid="ignore", divide="ignore"):
            out: F64 = np.where(c > 0, np.sqrt(np.maximum(self._tot_s.T, 0.0) / c), math.nan)
        span: F64 = self._tot_n.astype(np.float64) * self.sample_time
        return out, span

    def summary(self, digits: int | None = None) -> AccuracySummary:
        """The numbers the stream, ``/api/snapshot`` and ``/metrics`` show.

        ``{"mode": "truth" | "measured_force" | "none", "against": mode or None,
        "reason": str, "windows": [s, ...], "span": [s, ...], "rms": {name: [per
        window]}, "rms_q": {name: [...]}, "floor": [...]}``: ``rms`` against the truth
        (mode ``truth``) or the measured force (``measured_force``); NaN with mode
        ``none`` (``reason`` says why); ``rms_q`` against the Q(s)-filtered truth and
        ``floor`` (Q(s) F - F) only with the truth (else empty and NaN). ``digits``: each
        value rounded to that many significant digits and non-finite ones ``None``
        (JSON-safe, for the stream).
        """
        r, span = self.rms()
        k = len(self.names)
        rows: list[list[float | None]] = _rounded(r, digits) if digits else r.tolist()
        truth = self.has_truth
        nothing: list[float | None] = [None if digits else math.nan] * len(self.windows)
        ref = self.reference
        return {
            "mode": ref,
            "against": None if ref == "none" else ref,
            "reason": NO_REFERENCE if ref == "none" else "",
            "windows": list(self.windows),
            "span": _rounded(span[None, :], digits)[0] if digits else span.tolist(),
            "rms": dict(zip(self.names, rows[:k], strict=True)),
            "rms_q": dict(zip(self.names, rows[k : 2 * k], strict=True)) if truth else {},
            "floor": rows[-1] if truth else nothing,
        }


def _rounded(a: F64, digits: int) -> list[list[float | None]]:
    """Each value of a 2-D array to ``digits`` significant digits; non-finite ``None``."""
    fin = np.isfinite(a)
    m = np.where(fin & (a != 0.0), np.abs(a), 1.0)
    scale = 10.0 ** (digits - 1 - np.floor(np.log10(m)))
    out = np.where(fin, np.rint(np.where(fin, a, 0.0) * scale) / scale, 0.0).tolist()
    if fin.all():
        return out
    return [
        [v if ok else None for v, ok in zip(row, oks, strict=True)]
        for row, oks in zip(out, fin.tolist(), strict=True)
    ]
