"""The harmonic observer (seed 002's DFO) on the two-inertia stage's cutting-force estimate.

The cutting force observer of seed 000 returns :math:`\\hat F \\approx Q(s) F_{cut}`: its
low-pass Q(s) (250 Hz, first order) attenuates and delays the tooth-passing harmonics of
the force (100 and 200 Hz). Their frequencies are known (spindle speed x flutes and
multiples), so a harmonic observer whose channel is Q(s) estimates each harmonic's
amplitude and phase *before* Q and rebuilds the force without Q's attenuation and lag.
Its frequencies follow a spindle-speed change (seed 001 Fig. 9: gain and frequency x0.8
at 11 s) and it re-converges.

The truth is used only for scoring: the error of the estimate against the true force, at
100 and 200 Hz, before (observer output) and after (the DFO's reconstruction).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np

from common.arrays import F64
from estimators import dfo as dfo_mod
from estimators.force_observer import ObserverParams
from machine.stage import SEED001_FORCE, CuttingForce, StageConfig
from machine.stage_params import preset
from server.pipeline.stage_run import StageRun

BLOCK = 125  # 50 ms at 2.5 kHz


def q_channel(p: ObserverParams) -> tuple[tuple[float, ...], tuple[float, ...]]:
    """Continuous ``Q(s) = (w_c / (s + w_c))^n`` of the force observer, as (num, den)."""
    wc = 2 * math.pi * p.q_hz
    den = np.polynomial.polynomial.polypow([wc, 1.0], int(p.q_order))[::-1]
    return (wc ** int(p.q_order),), tuple(float(x) for x in den)


def make_dfo(p: ObserverParams, frequencies: tuple[float, ...]) -> dfo_mod.DfoParams:
    """The DFO on Q's output: harmonics plus the force's mean (offset state)."""
    num, den = q_channel(p)
    # channel poles at Q's own bandwidth: the observer needs no faster channel states
    return dfo_mod.DfoParams(
        frequencies=frequencies,
        sample_time=p.sample_time,
        channel_num=num,
        channel_den=den,
        include_offset=True,
        channel_bandwidth_hz=p.q_hz,
    )


@dataclass
class StageHarmonicsRun:
    """Per-sample signals of one run (estimates aligned with the true force)."""

    t: F64
    f_true: F64
    f_observer: F64
    f_dfo: F64
    amplitude: F64  # (n, K) the DFO's harmonic amplitudes
    true_amplitude: F64  # (n, K) gain * amplitude of the simulated force
    change_time: float | None


def run_stage(
    duration: float, *, change_time: float | None = None, factor: float = 0.8, seed: int = 0
) -> StageHarmonicsRun:
    """Run the seed 001 stage with the DFO on the fixed-parameter observer's output.

    At ``change_time`` the spindle speed changes: the force's gain and frequencies scale
    by ``factor`` (seed 001 Fig. 9) and the DFO is retuned to the new frequencies at the
    same block, keeping its state.
    """
    force: CuttingForce = SEED001_FORCE
    cfg = StageConfig(params=preset("seed001"), force=force)
    run = StageRun(cfg, seed=seed)
    fp = run.front.params
    obs = dfo_mod.Dfo(make_dfo(fp, tuple(force.frequencies)))
    st = obs.initial_state()
    n_blocks = round(duration / (BLOCK * cfg.sample_time))
    out: dict[str, list[F64]] = {k: [] for k in ("t", "ft", "fo", "fd", "amp", "tamp")}
    changed = False
    for _ in range(n_blocks):
        if change_time is not None and not changed and run.sim.t >= change_time - 1e-9:
            new_force = replace(force, gain=factor, freq_scale=factor)
            run.sim.reconfigure(force=new_force)
            obs = dfo_mod.Dfo(
                obs.params.with_frequencies(tuple(factor * f for f in force.frequencies))
            )
            force = new_force
            changed = True
        blk = run.step(BLOCK)
        st, rec = obs.step(st, blk.f_fixed)
        out["t"].append(blk.t_est)
        out["ft"].append(blk.f_true)
        out["fo"].append(blk.f_fixed)
        out["fd"].append(rec.d_hat)
        out["amp"].append(rec.amplitude)
        out["tamp"].append(np.tile(np.asarray(force.amplitudes) * force.gain, (BLOCK, 1)))
    return StageHarmonicsRun(
        t=np.concatenate(out["t"]),
        f_true=np.concatenate(out["ft"]),
        f_observer=np.concatenate(out["fo"]),
        f_dfo=np.concatenate(out["fd"]),
        amplitude=np.concatenate(out["amp"]),
        true_amplitude=np.concatenate(out["tamp"]),
        change_time=change_time,
    )


def error_at(
    run: StageHarmonicsRun, freqs: tuple[float, ...], t0: float, t1: float
) -> dict[str, list[float]]:
    """Amplitude [N m] of the estimation error at ``freqs`` over ``[t0, t1)``, before
    (observer output) and after (DFO), single-sided spectrum over whole periods."""
    sel = (run.t >= t0) & (run.t < t1)
    ts = float(np.median(np.diff(run.t)))
    out: dict[str, list[float]] = {"before": [], "after": []}
    for key, est in (("before", run.f_observer), ("after", run.f_dfo)):
        e = (run.f_true - est)[sel]
        spec = np.abs(np.fft.rfft(e)) * 2.0 / e.size
        f = np.fft.rfftfreq(e.size, ts)
        out[key] = [float(spec[int(np.argmin(np.abs(f - h)))]) for h in freqs]
    return out


def reconvergence_time(run: StageHarmonicsRun, tol: float = 0.05) -> float:
    """Seconds after the change until every amplitude estimate stays within ``tol``
    (relative) of the new true amplitude; ``inf`` if it never does."""
    if run.change_time is None:
        raise ValueError("run has no spindle-speed change")
    after = run.t >= run.change_time
    rel = np.max(np.abs(run.amplitude / run.true_amplitude - 1.0), axis=1)
    bad = np.nonzero(after & (rel > tol))[0]
    if bad.size == 0:
        return 0.0
    last = int(bad[-1])
    if last == run.t.size - 1:
        return math.inf
    return float(run.t[last + 1] - run.change_time)
