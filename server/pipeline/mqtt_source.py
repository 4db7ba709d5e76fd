"""A machine's drive data from an MQTT broker as a measurement source.

:class:`MqttSource` satisfies :class:`server.pipeline.sources.MeasurementSource` over a
:class:`server.pipeline.drive_feed.DriveFeed`: each :meth:`MqttSource.step` hands out the
samples received so far (up to ``n``; none when nothing has arrived), and marks the first
block after a gap, a time jump, a restart or a dropped flood as a discontinuity, so the
pipeline resets its observers instead of bridging the hole.

What the observers are built from (sample time, nominal parameters, encoder) comes from
the retained ``meta`` message. Until it has arrived the source hands out nothing
(``status()["state"] == "waiting for meta"``); when a new meta changes those, the source
says ``needs_rebuild`` and the live loop builds a new pipeline on :meth:`renewed` (the
clients get a new hello). The live observers are two-inertia: a ``rigid`` feed (no load
encoder) is refused in ``status()`` with the reason and its blocks are not observed.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from common.errors import ParameterError
from machine.params import preset
from machine.stage import SEED000_FORCE, Measurements, StageConfig
from server.pipeline.drive_feed import DriveFeed
from server.pipeline.sources import (
    NOMINAL,
    RESUMED,
    ConfiguredSource,
    SourceBlock,
    empty_measurements,
    nominal_config,
)


class MqttSource(ConfiguredSource):
    """The live feed of one machine (see the module docstring)."""

    name = "mqtt"
    kind = "two_inertia"
    has_truth = False
    knobs_apply = False
    paced = False
    finished = False

    def __init__(self, feed: DriveFeed) -> None:
        self.feed = feed
        self._gen = feed.meta_generation
        meta = feed.meta
        self.problem = ""
        self._cfg = StageConfig(params=preset("seed000"), force=SEED000_FORCE)
        self.ready = False
        if meta is not None:
            self._configure(meta)
        self._t = 0.0
        self._t0: float | None = None
        self._taken = 0
        self._resumed = False  # restored from a checkpoint: the next block says so
        self.last_wall: float | None = None

    def _configure(self, meta: dict[str, Any]) -> None:
        if meta.get("kind") != "two_inertia":
            self.problem = (
                f"meta kind {meta.get('kind')!r}: the live observers need a 'two_inertia' "
                "feed (motor and load positions)"
            )
            return
        units = meta.get("units", {})
        if units.get("position") != "rad" or units.get("effort") not in ("N m", "A"):
            self.problem = (
                f"meta units {units!r}: the live observers need position 'rad' and effort "
                "'N m' (or 'A' with K_t)"
            )
            return
        nom = meta.get("nominal") or {}
        missing = [k for k in NOMINAL if k not in nom]
        if missing:
            self.problem = (
                f"meta nominal lacks {', '.join(missing)} (expected {', '.join(NOMINAL)})"
            )
            return
        try:
            self._cfg = nominal_config(
                nom, float(meta["sample_time"]), meta.get("encoder_resolution")
            )
        except (ParameterError, TypeError, ValueError) as exc:
            self.problem = f"meta nominal parameters: {exc}"
            return
        self.ready = True

    # -- MeasurementSource -------------------------------------------------------------

    @property
    def t(self) -> float:
        return self._t

    @property
    def needs_rebuild(self) -> bool:
        """True when a (new) meta arrived after this source was built."""
        return self.feed.meta_generation != self._gen

    def renewed(self) -> MqttSource:
        """A source on the same feed, built from its current meta."""
        return MqttSource(self.feed)

    def step(self, n: int) -> SourceBlock:
        if not self.ready or self.needs_rebuild:
            return SourceBlock(empty_measurements())
        take = self.feed.take(max(int(n), 0))
        if take.n == 0:
            return SourceBlock(empty_measurements())
        c = take.columns
        ts = self.sample_time
        k_t = self._cfg.params.K_t
        if "tau_m" in c:
            tau = c["tau_m"]
            i_m = tau / k_t
        else:
            i_m = c["i_m"]
            tau = i_m * k_t
        q_l = c.get("q_l")
        if q_l is None:
            self.problem = "drive blocks without q_l: the live observers need the load position"
            return SourceBlock(empty_measurements())
        disc = ("; ".join(take.reasons) or "gap") if take.discontinuity else None
        if self._resumed:  # the first block after a restart (sources.RESUMED)
            disc, self._resumed = RESUMED, False
        t0 = float(take.t[0])
        if self._t0 is None:  # the source's time counts from its first sample
            self._t0 = t0 - self._t
        elif disc is not None and t0 - self._t0 < self._t:
            self._t0 = t0 - self._t  # the publisher restarted: time goes on, never back
        # on the sample grid, as a replayed log's (sample index x sample time); across a
        # gap the index jumps forward with the feed's time
        k0 = round((t0 - self._t0) / ts)
        t = (k0 + np.arange(take.n, dtype=np.float64)) * ts
        self._t = float(t[-1] + ts)
        self._taken += take.n
        f = c.get("f_ext")
        meas = Measurements(
            t=t,
            i_m=i_m,
            tau_m=tau,
            q_m=c["q_m"],
            q_l=q_l,
            f_ext=f if f is not None else np.full(take.n, math.nan),
        )
        self.last_wall = self.feed.last_wall
        return SourceBlock(meas, None, disc)

    def reconfigure(self, **changes: object) -> None:
        """Knobs do not change a real machine."""

    def reset(self) -> None:
        """A live feed cannot rewind: time restarts at 0 with the next samples."""
        self._t = 0.0
        self._t0 = None

    def state(self) -> object:
        """The source's time [s]: a live feed is not ours to keep (the machine goes on
        without us), but its time goes on from where it was."""
        return float(self._t)

    def restore(self, state: object) -> None:
        """Continue the time at ``state`` [s]; the next block is marked
        :data:`~server.pipeline.sources.RESUMED`.

        Raises
        ------
        ParameterError
            Not a time.
        """
        if not isinstance(state, float) or not math.isfinite(state) or state < 0:
            raise ParameterError("source", "a time >= 0 s", state)
        self._t, self._t0, self._resumed = state, None, True

    def truth_summary(self) -> dict[str, object]:
        return {"machine": self.feed.machine}

    def status(self) -> dict[str, object]:
        if self.problem:
            state = "refused"
        elif not self.ready:
            state = "waiting for meta"
        elif not self.feed.connected:
            state = "broker not connected"
        else:
            state = "receiving"
        return {"state": state, "problem": self.problem, **self.feed.health()}
