"""Blocks on one time grid from change-only, node-by-node samples (opcua_grid.py)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from common.errors import ParameterError
from server.pipeline.opcua_grid import TimeGrid

T = 0.1


def test_samples_land_on_their_nearest_grid_point_and_quiet_nodes_are_held() -> None:
    g = TimeGrid(["a", "b"], T)
    # a changes every cell, b only twice; the server stamps them a few ms apart
    for k in range(10, 20):
        g.add("a", k * T + 0.003, float(k))
    g.add("b", 10 * T - 0.004, 1.0)
    g.add("b", 15 * T + 0.02, 2.0)
    blk = g.advance(19.5 * T)
    assert blk.n == 10 and blk.discontinuity is None
    np.testing.assert_allclose(blk.t, np.arange(10, 20) * T)
    np.testing.assert_array_equal(blk.columns["a"], np.arange(10, 20, dtype=float))
    np.testing.assert_array_equal(blk.columns["b"], [1.0] * 5 + [2.0] * 5)
    c = g.counts
    assert c.held == {"a": 0, "b": 8} and c.lost == 0 and c.merged == 0 and c.cells == 10


def test_nothing_is_handed_out_beyond_the_watermark_or_before_every_node_has_a_value() -> None:
    g = TimeGrid(["a", "b"], T)
    g.add("a", 1.0, 1.0)
    assert g.advance(5.0).n == 0  # b has no value yet: nothing is invented
    g.add("b", 1.2, 2.0)
    blk = g.advance(1.25)  # the cell of 1.2 ends at 1.25
    np.testing.assert_allclose(blk.t, [1.2])  # starts where both have a value
    assert blk.columns["a"][0] == 1.0  # a's value, in effect before the start
    g.add("a", 1.3, 3.0)
    assert g.advance(1.26).n == 0  # the cell of 1.3 is not complete yet
    blk = g.advance(1.35)
    assert blk.columns["a"].tolist() == [3.0] and blk.columns["b"].tolist() == [2.0]


def test_late_merged_and_overflowed_samples_are_counted_never_placed_in_the_past() -> None:
    g = TimeGrid(["a"], T)
    for k in range(5):
        g.add("a", k * T, float(k))
    g.advance(4.5 * T)
    g.add("a", 2 * T, 99.0)  # arrives after its cell went out
    g.add("a", 5 * T, 5.0)
    g.add("a", 5 * T + 0.01, 5.5)  # two samples in one cell: the later one
    g.add("a", 6 * T, 6.0, overflow=True)
    blk = g.advance(6.5 * T)
    assert blk.columns["a"].tolist() == [5.5, 6.0]
    assert g.counts.late == 1 and g.counts.merged == 1 and g.counts.lost == 1


def test_a_gap_is_not_bridged_it_is_counted_and_said() -> None:
    g = TimeGrid(["a", "b"], T)
    for k in range(3):
        g.add("a", k * T, 1.0)
        g.add("b", k * T, 1.0)
    assert g.advance(1.5 * T).n == 2
    g.add("a", 2 * T, 1.5)  # arrived before the gap, its cell not handed out yet
    g.restart("reconnected")
    g.add("a", 8 * T, 2.0)  # a alone is not a start: every node needs a new value
    g.add("b", 9 * T, 2.0)
    rest = g.advance(9.5 * T)  # the cells before the gap first, as they are
    assert rest.discontinuity is None and rest.columns["a"].tolist() == [1.5]
    assert rest.columns["b"].tolist() == [1.0]
    blk = g.advance(9.5 * T)
    np.testing.assert_allclose(blk.t, [0.9])  # the first cell both have new values
    assert blk.discontinuity == "reconnected"
    assert blk.columns["a"].tolist() == [2.0]
    assert g.counts.lost == 6 * 2 and g.counts.gaps == 1  # cells 3..8 never came whole
    assert g.advance(9.5 * T).discontinuity is None


def test_a_grid_needs_a_positive_sample_time_and_a_node() -> None:
    with pytest.raises(ParameterError, match="sample_time"):
        TimeGrid(["a"], math.nan)
    with pytest.raises(ParameterError, match="nodes"):
        TimeGrid([], T)
