"""Blocks on one time grid from an OPC UA subscription's data changes.

A subscription reports a node when its value changed, and the server samples the nodes
one by one: the samples of a block arrive node by node, each stamped with its
``SourceTimestamp`` (the ``ServerTimestamp`` when the source gives none). A
:class:`TimeGrid` puts them on one grid ``t_k = k * sample_time`` of the server's clock:

- a sample belongs to the cell of its nearest grid point (``(t_k - T/2, t_k + T/2]``);
- a node with no sample in a cell holds its last value there (sample and hold: the
  subscription said nothing because nothing changed), and each held value is counted
  (:attr:`GridCounts.held`, per node);
- a second sample of a node in one cell replaces the first, counted
  (:attr:`GridCounts.merged`: the server sampled faster than the grid);
- a sample older than the cells already handed out is counted late and only updates the
  held value (:attr:`GridCounts.late`): nothing is invented in the past;
- the grid hands out cells only up to a *watermark*, the server's time the caller knows
  every sample of has arrived (the newest timestamp less a publishing interval, or the
  server's clock during quiet spells), so a slow node is not held by mistake;
- the server's Overflow bit (a queue that dropped samples) adds to :attr:`GridCounts.lost`;
  a gap in the feed (a lost connection) is not bridged: :meth:`TimeGrid.restart` starts the
  grid again at the next cell every node has a value in, counting the cells between as
  lost, and the first block after it says ``discontinuity``.

Nothing here knows OPC UA: :mod:`server.pipeline.opcua_source` feeds it.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import TypedDict

import numpy as np

from common.arrays import F64
from common.errors import ParameterError

__all__ = ["GridBlock", "GridCounts", "TimeGrid"]


class GridCountsDict(TypedDict):
    """:meth:`GridCounts.as_dict` (a source's status carries these)."""

    samples: int
    cells: int
    held: dict[str, int]
    held_total: int
    merged: int
    late: int
    lost: int
    gaps: int


@dataclass
class GridCounts:
    """What the grid did, since the start (per node where it says so)."""

    samples: int = 0  #: samples received
    cells: int = 0  #: grid points handed out
    held: dict[str, int] = field(default_factory=dict)  #: per node: values held
    merged: int = 0  #: samples replaced by a later one in the same cell
    late: int = 0  #: samples older than the cells already handed out
    lost: int = 0  #: samples the server dropped (Overflow) or a gap skipped
    gaps: int = 0  #: restarts after a gap

    def as_dict(self) -> GridCountsDict:
        return {
            "samples": self.samples,
            "cells": self.cells,
            "held": dict(self.held),
            "held_total": sum(self.held.values()),
            "merged": self.merged,
            "late": self.late,
            "lost": self.lost,
            "gaps": self.gaps,
        }


@dataclass(frozen=True)
class GridBlock:
    """Cells handed out: their server times ``t`` [s], one column per node (by name),
    and ``discontinuity`` (a reason, or None when it continues the last block)."""

    t: F64
    columns: dict[str, F64]
    discontinuity: str | None = None

    @property
    def n(self) -> int:
        return len(self.t)


class TimeGrid:
    """The grid of ``nodes`` at ``sample_time`` (see the module docstring)."""

    def __init__(self, nodes: Sequence[str], sample_time: float) -> None:
        if not (math.isfinite(sample_time) and sample_time > 0):
            raise ParameterError("sample_time", "a time > 0 s", sample_time)
        if not nodes:
            raise ParameterError("nodes", "at least one node", list(nodes))
        self.nodes = tuple(nodes)
        self.sample_time = float(sample_time)
        self.counts = GridCounts(held={n: 0 for n in self.nodes})
        self._cells: dict[int, dict[str, float]] = {}  # cell -> node -> value
        self._last: dict[str, float] = {}  # node -> the value in effect
        self._next: int | None = None  # the next cell to hand out
        self._pending_disc: str | None = None
        self._resume_from: int | None = None  # the cell a gap began at
        self._flushed: GridBlock | None = None  # the cells before a gap, not handed out

    def cell(self, ts: float) -> int:
        """The cell of a timestamp (the nearest grid point)."""
        return math.ceil(ts / self.sample_time - 0.5)

    def add(self, node: str, ts: float, value: float, overflow: bool = False) -> None:
        """One sample of ``node`` at server time ``ts`` [s]; ``overflow``: the server's
        queue dropped samples before this one (at least one is counted lost)."""
        c = self.counts
        c.samples += 1
        if overflow:
            c.lost += 1
        k = self.cell(ts)
        if self._next is not None and k < self._next:
            c.late += 1
            self._last[node] = float(value)
            return
        slot = self._cells.setdefault(k, {})
        if node in slot:
            c.merged += 1
        slot[node] = float(value)

    def restart(self, reason: str = "gap") -> None:
        """After a gap: the cells that arrived before it are handed out as they are (the
        next :meth:`advance` returns them); then the grid starts again at the first cell
        every node has a new value in, the cells between counted lost, and the block
        from there says ``reason``."""
        if self._next is None:
            return
        if self._cells:
            self._flushed = self._emit(max(self._cells), None)
        self.counts.gaps += 1
        self._pending_disc = reason
        self._resume_from = self._next
        self._next = None

    def _start(self, upto: int) -> int | None:
        """The first cell at which every node has a value (None: not yet); after a gap,
        a new value each."""
        have = set(self._last) if self._resume_from is None else set()
        for k in sorted(self._cells):
            if k > upto:
                return None
            have |= set(self._cells[k])
            if have >= set(self.nodes):
                return k
        return None

    def advance(self, watermark: float) -> GridBlock:
        """The cells up to the server time ``watermark`` [s] (every sample up to it has
        arrived), sample-and-hold filled, as a block (empty when there is none)."""
        if self._flushed is not None:  # the cells before a gap first
            out, self._flushed = self._flushed, None
            return out
        # a cell is complete once the watermark passes its upper edge t_k + T/2
        upto = math.floor(watermark / self.sample_time - 0.5 + 1e-9)
        if self._next is None:
            first = self._start(upto)
            if first is None:
                return self._empty()
            resume = self._resume_from
            if resume is not None and first > resume:
                self.counts.lost += (first - resume) * len(self.nodes)
            self._resume_from = None
            for k in [k for k in self._cells if k < first]:  # before the start: the
                self._last.update(self._cells.pop(k))  # values in effect, not samples
            self._next = first
        if upto < self._next:
            return self._empty()
        disc, self._pending_disc = self._pending_disc, None
        return self._emit(upto, disc)

    def _emit(self, upto: int, disc: str | None) -> GridBlock:
        """The cells from the next one to ``upto``, sample-and-hold filled."""
        assert self._next is not None
        ks = np.arange(self._next, upto + 1)
        cols = {n: np.empty(len(ks)) for n in self.nodes}
        held = self.counts.held
        for i, k in enumerate(ks):
            slot = self._cells.pop(int(k), None) or {}
            for n in self.nodes:
                if n in slot:
                    self._last[n] = slot[n]
                else:
                    held[n] += 1
                cols[n][i] = self._last.get(n, math.nan)
        self._next = upto + 1
        self.counts.cells += len(ks)
        return GridBlock(ks.astype(np.float64) * self.sample_time, cols, disc)

    def _empty(self) -> GridBlock:
        return GridBlock(np.zeros(0), {n: np.zeros(0) for n in self.nodes})
