"""Replay a measured two-inertia log through the live observers (issue 4 section 7).

:class:`ReplayPipeline` is a :class:`server.pipeline.live_pipeline.LivePipeline` whose stage is a
:class:`ReplaySim`: instead of simulating, it hands out the log's Measurements (``t``,
``tau_m``, ``q_m``, ``q_l``) block by block, with the log's ``f_ext`` as the "true" force
(NaN when the log has none). Everything after the simulator is the live pipeline's
own :class:`server.pipeline.stage_run.StageRun` (TorsionEstimator, LoadIdentifier, cutting_force),
so the replayed log meets the same observers as the simulated stage. The observers are
built from the sidecar's nominal parameters. The replay ends at the log's last sample:
``finished`` turns true and the live loop pauses.

Validation (:func:`open_replay`): the file exists, passes
:func:`server.records.measured_log.load_log`,
is of kind ``two_inertia`` with a ``q_l`` column, angles in rad, effort in N m (or A with
K_t), and its sidecar gives the nominal parameters J_M, J_L, K, K_t, B_M, B_L, F_CM, F_CL.
"""

from __future__ import annotations

import math
import os
from typing import Any

import numpy as np

from estimators.errors import ParameterError
from estimators.observer_effects import ObserverEffect
from estimators.rls import IdentifierParams
from machine.params import StageParams
from machine.stage import SEED000_FORCE, Measurements, StageConfig, Truth
from server.errors import CutwatchError, LogFormatError
from server.pipeline.live_pipeline import LivePipeline, _knobs
from server.records.measured_log import MeasuredLog, load_log

NOMINAL = ("J_M", "J_L", "K", "K_t", "B_M", "B_L", "F_CM", "F_CL")


class ReplaySim:
    """The log as a stage: ``step(n)`` returns its next ``n`` samples (fewer at the end).

    Has the parts of :class:`machine.stage.StageSim` the pipeline uses (``t``,
    ``config``, ``step``, ``reconfigure``); ``reconfigure`` does nothing (a log cannot be
    changed by the knobs).
    """

    def __init__(self, log: MeasuredLog, config: StageConfig) -> None:
        self.log = log
        self.config = config
        self.k = 0
        self.n = len(log["t"])
        c = log.columns
        self._f = c["f_ext"] if "f_ext" in c else np.full(self.n, math.nan)

    @property
    def t(self) -> float:
        """Time of the next sample [s] (counted from the log's first sample)."""
        return self.k * self.config.sample_time

    @property
    def remaining(self) -> int:
        return self.n - self.k

    def reconfigure(self, **changes: object) -> None:
        """Knobs do not change a recorded log."""

    def step(self, n: int) -> tuple[Measurements, Truth]:
        a, b = self.k, min(self.k + int(n), self.n)
        self.k = b
        c = self.log.columns
        ts = self.config.sample_time
        t = np.arange(a, b, dtype=np.float64) * ts
        tau = c["tau_m"][a:b]
        k_t = self.config.params.K_t
        nan = np.full(b - a, math.nan)
        meas = Measurements(
            t=t,
            i_m=c["i_m"][a:b] if "i_m" in c else tau / k_t,
            tau_m=tau,
            q_m=c["q_m"][a:b],
            q_l=c["q_l"][a:b],
            f_ext=self._f[a:b],
        )
        truth = Truth(
            f_cut=self._f[a:b],
            omega_m=nan,
            omega_l=nan,
            t_s=nan,
            omega_ref=nan,
            J_L=nan,
            B_L=nan,
            F_CL=nan,
        )
        return meas, truth


def open_replay(path: str | os.PathLike[str]) -> MeasuredLog:
    """Load and check a log for replay.

    Raises
    ------
    LogFormatError
        The file is missing or fails the log-format checks.
    CutwatchError
        Not a two-inertia log in rad / N m with the nominal parameters.
    """
    log = load_log(path, required=("t", "tau_m", "q_m", "q_l"))
    if log.kind != "two_inertia":
        raise CutwatchError(
            f"{log.path}: kind {log.kind!r}: expected 'two_inertia' (sidecar key 'kind')"
        )
    if log.units.get("position") != "rad" or log.units.get("effort") != "N m":
        raise CutwatchError(
            f"{log.path}: units {log.units!r}: expected position 'rad' and effort 'N m' "
            "(the live observers work on motor and load angles)"
        )
    missing = [k for k in NOMINAL if k not in log.nominal]
    if missing:
        raise CutwatchError(
            f"{log.path}: sidecar 'nominal' lacks {', '.join(missing)} "
            f"(expected {', '.join(NOMINAL)})"
        )
    if len(log["t"]) < 2:
        raise LogFormatError(f"{log.path}: expected at least 2 samples, found {len(log['t'])}")
    return log


def _config(log: MeasuredLog) -> StageConfig:
    nom = log.nominal
    try:
        p = StageParams(**{k: nom[k] for k in NOMINAL}, C_s=nom.get("C_s", 0.0))
        res = log.sidecar.get("encoder_resolution")
        bits = 20 if res is None else round(math.log2(2 * math.pi / float(res)))
        return StageConfig(
            params=p, force=SEED000_FORCE, sample_time=log.sample_time, encoder_bits=bits
        )
    except (ParameterError, TypeError, ValueError) as exc:
        raise CutwatchError(f"{log.path}: nominal parameters: {exc}") from None


class ReplayPipeline(LivePipeline):
    """The live pipeline fed by a log instead of the simulated stage.

    Parameters
    ----------
    log : MeasuredLog
        From :func:`open_replay`.
    """

    def __init__(self, log: MeasuredLog, seed: int = 0) -> None:
        self.log = log
        self._cfg = _config(log)
        # LivePipeline.__init__ without its scenario check ("replay" is not a simulation)
        self.scenario = "replay"
        self.seed = seed
        self._knobs = _knobs()
        self.effects: tuple[ObserverEffect, ...] = ()
        self.reset()

    def _base(self) -> tuple[StageConfig, IdentifierParams, dict[str, float]]:
        return self._cfg, IdentifierParams(sample_time=self._cfg.sample_time), {}

    def reset(self) -> None:
        super().reset()
        self.replay = ReplaySim(self.log, self._cfg)
        self.run.sim = self.replay  # type: ignore[assignment]
        self._applied = ()
        self._apply(0.0)

    @property
    def finished(self) -> bool:
        """True once every sample of the log has been fed."""
        return self.replay.remaining <= 0

    def step(self, n: int) -> dict[str, np.ndarray]:
        n = min(int(n), max(self.replay.remaining, 0))
        if n == 0:
            return {c.name: np.zeros(0) for c in self.channels()} | {"t": np.zeros(0)}
        out = super().step(n)
        # no truth but f_ext: the true parameters and harmonics are unknown
        for k in ("h1_true", "h2_true", "vb_true", "vb_est", "vb_limit", "life_left"):
            out[k] = np.full_like(out[k], math.nan)
        return out

    def snapshot(self) -> dict[str, Any]:
        snap = super().snapshot()
        snap["truth"] = {"log": str(self.log.path), "samples": self.replay.n}
        snap["replay"] = {
            "path": str(self.log.path),
            "samples": self.replay.n,
            "fed": self.replay.k,
            "finished": self.finished,
        }
        return snap


__all__ = ["ReplayPipeline", "ReplaySim", "open_replay"]
