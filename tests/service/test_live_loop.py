"""The loop owns simulated time: after a host stall it catches up (no sample skipped or
repeated) and reports the lag; past max_lag_s it re-anchors and counts a stall."""

from __future__ import annotations

import time
from collections.abc import Callable, Iterator
from typing import Any

import numpy as np
import pytest
from _wait import poll

from server.errors import CutwatchError
from server.service.hub import Hub
from server.service.loop import LiveLoop
from server.service.settings import Settings


def wait_for(pred: Callable[[], bool], timeout: float = 20.0) -> Any:
    return poll(pred, timeout, 0.02)


@pytest.fixture
def recorded() -> Iterator[tuple[LiveLoop, list[np.ndarray]]]:
    loop = LiveLoop(Settings(scenario="default", viser=False), Hub(4))
    times: list[np.ndarray] = []
    step = loop.pipeline.step

    def recording_step(n: int) -> dict[str, np.ndarray]:
        out = step(n)
        times.append(out["t"])
        return out

    loop.pipeline.step = recording_step  # type: ignore[method-assign]
    loop.start()
    try:
        wait_for(lambda: loop.blocks > 5)
        yield loop, times
    finally:
        loop.stop()


def test_stall_is_caught_up_without_skipping_samples(
    recorded: tuple[LiveLoop, list[np.ndarray]],
) -> None:
    loop, times = recorded
    with loop.lock:  # the host stalls the loop for 0.6 s
        t_stall = loop.pipeline.t
        time.sleep(0.6)
    wait_for(lambda: loop.pipeline.t > t_stall + 1.0)
    assert max(loop._lags) > 0.4  # the lag was seen and reported
    assert loop.stalls == 0  # below max_lag_s: caught up, not re-anchored
    # caught up: simulated time is back on the wall-clock schedule
    wait_for(lambda: loop.lag_s < 0.05)
    t = np.concatenate(times[1:])  # after the warm-up block (reset there)
    dt = np.diff(t)
    np.testing.assert_allclose(dt, loop.pipeline.sample_time, rtol=1e-6)


def test_long_stall_reanchors_and_counts() -> None:
    loop = LiveLoop(Settings(scenario="default", viser=False, max_lag_s=0.2), Hub(4))
    loop.start()
    try:
        wait_for(lambda: loop.blocks > 3)
        with loop.lock:
            time.sleep(0.8)
        wait_for(lambda: loop.stalls >= 1)
        # back on the wall clock's schedule, not racing to make up the 0.8 s: from the
        # re-anchor on, the loop is never more than max_lag_s (+ a block) behind, so in
        # any window it runs at most the window's wall time plus that (a loop that raced
        # would run ~1.8 s in the 1 s). Not a rate floor: a loaded box may run slower than
        # real time (the rate is cutwatch bench's); only that it runs on at all.
        block_s = loop.block_n * loop.pipeline.sample_time
        w0 = time.monotonic()  # the wall window spans both reads of t
        t0 = loop.pipeline.t
        time.sleep(1.0)
        ran = loop.pipeline.t - t0
        wall = time.monotonic() - w0
        assert ran <= wall + 0.2 + block_s, (ran, wall)
        wait_for(lambda: loop.pipeline.t > t0 + ran)  # and it runs on
    finally:
        loop.stop()


def test_speed_out_of_range() -> None:
    loop = LiveLoop(Settings(scenario="default", viser=False), Hub(4))
    with pytest.raises(CutwatchError, match=r"speed: expected a value in \[0, 1000\], got -1"):
        loop.set_speed(-1)
    with pytest.raises(CutwatchError, match=r"speed: expected a value in \[0, 1000\], got nan"):
        loop.set_speed(float("nan"))
