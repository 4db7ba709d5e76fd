r"""Logs with one undeclared effect, for the residual loop's tests and its Monte Carlo.

Two kinds, both seeded so that one seed is one case that really differs from another:

* :func:`rigid_log`: a rigid axis written in closed form (M = 20 kg, Fv = 100 N s/m,
  Fc = 8 N, offset = -1 N, 1 kHz), plus one effect and Gaussian noise. Without a seed
  the record is the historical one of the tests (noise of ``default_rng(0)``, 1 N rms);
  with a seed the motion (amplitudes, frequencies and phases of the two sines), the
  noise level and the effect's magnitude and phase are drawn in the ranges of
  :data:`RIGID_RANGES`.
* :func:`stage_config` / :func:`simulate_stage`: the two-inertia simulator
  (``machine.stage``) as ``cutwatch simulate`` runs it. Without a seed: the defaults
  (speed 30 rad/s, reversals every 2 s, 0.3 s dwell, levels 1, 0.5, 0.25, no current
  noise, the effect at its default magnitude). With a seed: the motion program, the
  current noise and the effect's magnitude and phase are drawn in the ranges of
  :data:`STAGE_RANGES` and :meth:`machine.effects.PlantEffects.varied`.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np

from common.state_io import JsonNode

#: effects of the closed-form rigid log (besides "none")
RIGID_EFFECTS: tuple[str, ...] = (
    "position_periodic",
    "stribeck",
    "harmonic",
    "coulomb_asymmetry",
    "drift",
    "delay",
)
#: documented ranges of the seeded rigid log (uniform draws)
RIGID_RANGES: dict[str, tuple[float, float]] = {
    "amplitude_1": (0.04, 0.06),  # m, slow sine (default 0.05)
    "frequency_1": (0.25, 0.35),  # Hz (default 0.3)
    "amplitude_2": (0.007, 0.013),  # m, fast sine (default 0.01)
    "frequency_2": (0.9, 1.3),  # Hz (default 1.1)
    "noise": (0.8, 1.2),  # N rms (default 1)
    "magnitude": (0.7, 1.3),  # factor on the effect's default size
}
#: documented ranges of the seeded simulator log (uniform draws)
STAGE_RANGES: dict[str, tuple[float, float]] = {
    "speed": (20.0, 40.0),  # rad/s plateau (default 30)
    "half_period": (1.5, 2.5),  # s between reversals (default 2)
    "dwell": (0.15, 0.45),  # s at rest at each reversal (default 0.3)
    "level_2": (0.4, 0.7),  # second plateau, fraction of the speed (default 0.5)
    "level_3": (0.15, 0.35),  # third plateau (default 0.25); the three in random order
    "current_noise": (0.01, 0.05),  # A rms (default 0)
}
RIGID_SIDECAR: dict[str, JsonNode] = {
    "units": {"effort": "N", "position": "m"},
    "kind": "rigid",
    "sample_time": 1e-3,
}


def _u(rng: np.random.Generator, key: str, ranges: dict[str, tuple[float, float]]) -> float:
    lo, hi = ranges[key]
    return float(rng.uniform(lo, hi))


def rigid_log(effect: str, n: int = 20000, seed: int | None = None) -> dict[str, np.ndarray]:
    """A rigid axis (M=20, Fv=100, Fc=8, offset=-1) with one undeclared ``effect``.

    ``seed=None`` gives the fixed record the tests were written on; an integer draws
    the motion, noise and effect (see :data:`RIGID_RANGES`).
    """
    if effect != "none" and effect not in RIGID_EFFECTS:
        raise ValueError(
            f"effect: expected none or one of {', '.join(RIGID_EFFECTS)}, got {effect}"
        )
    t = np.arange(n) * 1e-3
    if seed is None:
        rng = np.random.default_rng(0)
        a1, f1, a2, f2, ph2, ph1 = 0.05, 0.3, 0.01, 1.1, 0.3, 0.0
        noise, mag, eph = 1.0, 1.0, 0.0
    else:
        draw = np.random.default_rng([12, seed])
        a1 = _u(draw, "amplitude_1", RIGID_RANGES)
        f1 = _u(draw, "frequency_1", RIGID_RANGES)
        a2 = _u(draw, "amplitude_2", RIGID_RANGES)
        f2 = _u(draw, "frequency_2", RIGID_RANGES)
        ph1, ph2 = (float(x) for x in draw.uniform(0.0, 2 * np.pi, 2))
        noise = _u(draw, "noise", RIGID_RANGES)
        mag = _u(draw, "magnitude", RIGID_RANGES)
        eph = float(draw.uniform(0.0, 2 * np.pi))
        rng = np.random.default_rng([13, seed])
    w1, w2 = 2 * np.pi * f1, 2 * np.pi * f2

    def motion(tt: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        q = a1 * np.sin(w1 * tt + ph1) + a2 * np.sin(w2 * tt + ph2)
        qd = a1 * w1 * np.cos(w1 * tt + ph1) + a2 * w2 * np.cos(w2 * tt + ph2)
        qdd = -a1 * w1**2 * np.sin(w1 * tt + ph1) - a2 * w2**2 * np.sin(w2 * tt + ph2)
        return q, qd, qdd

    q, qd, qdd = motion(t)
    if effect == "delay":  # the whole effort acts 10 ms late (x magnitude)
        _, qd, qdd = motion(t - 0.01 * mag)
    f = 20 * qdd + 100 * qd + 8 * np.sign(qd) - 1.0
    extras: dict[str, Callable[[], np.ndarray]] = {
        "none": lambda: np.zeros(n),
        "position_periodic": lambda: 3 * mag * np.sin(2 * np.pi * q / 0.0025 + 0.5 + eph),
        "stribeck": lambda: 10 * mag * np.sign(qd) * np.exp(-((np.abs(qd) / 0.01) ** 2)),
        "harmonic": lambda: 3 * mag * np.sin(2 * np.pi * 7.3 * t + eph),
        "coulomb_asymmetry": lambda: 40 * mag * np.abs(qd),
        "drift": lambda: 0.3 * mag * t,
        "delay": lambda: np.zeros(n),
    }
    extra = extras[effect]()
    return {"t": t, "tau_m": f + extra + rng.normal(0.0, noise, n), "q_m": q}


@dataclass(frozen=True)
class StageCase:
    """The drawn (or default) motion program, noise and effects of one simulator log."""

    speed: float
    half_period: float
    dwell: float
    levels: tuple[float, ...]
    current_noise: float
    effects: Any  # machine.effects.PlantEffects


def stage_case(
    effects: list[str] | tuple[str, ...],
    seed: int | None = None,
    *,
    speed: float | None = None,
    half_period: float | None = None,
    dwell: float | None = None,
    levels: tuple[float, ...] | None = None,
    current_noise: float | None = None,
    vary: frozenset[str] = frozenset({"motion", "noise", "effect"}),
) -> StageCase:
    """Motion, noise and effects of a simulator log; explicit values win over draws.

    ``vary`` limits what a seed draws (``motion``, ``noise``, ``effect``): a second
    record of the same machine keeps ``effect`` out of it.
    """
    from machine.effects import PlantEffects

    eff = PlantEffects().with_enabled(*effects)
    default = StageCase(30.0, 2.0, 0.3, (1.0, 0.5, 0.25), 0.0, eff)
    if seed is None:
        drawn = default
    else:
        rng = np.random.default_rng([7, seed])
        sp = _u(rng, "speed", STAGE_RANGES)
        hp = _u(rng, "half_period", STAGE_RANGES)
        dw = _u(rng, "dwell", STAGE_RANGES)
        lv = [1.0, _u(rng, "level_2", STAGE_RANGES), _u(rng, "level_3", STAGE_RANGES)]
        lv = [lv[i] for i in rng.permutation(3)]
        cn = _u(rng, "current_noise", STAGE_RANGES)
        ev = eff.varied(rng)
        drawn = StageCase(
            sp if "motion" in vary else default.speed,
            hp if "motion" in vary else default.half_period,
            dw if "motion" in vary else default.dwell,
            tuple(lv) if "motion" in vary else default.levels,
            cn if "noise" in vary else default.current_noise,
            ev if "effect" in vary else default.effects,
        )
    return StageCase(
        drawn.speed if speed is None else speed,
        drawn.half_period if half_period is None else half_period,
        drawn.dwell if dwell is None else dwell,
        drawn.levels if levels is None else levels,
        drawn.current_noise if current_noise is None else current_noise,
        drawn.effects,
    )


def simulate_stage(
    case: StageCase,
    seconds: float,
    *,
    seed: int | None = None,
    preset_name: str = "seed000",
    weight: bool = False,
    no_force: bool = False,
    on_block: Callable[[int], None] | None = None,
) -> tuple[dict[str, np.ndarray], dict[str, Any], dict[str, Any]]:
    """Run the simulator: the log's columns, its sidecar and the truth (for scoring)."""
    from machine.stage import (
        SEED000_FORCE,
        SEED001_FORCE,
        CuttingForce,
        StageConfig,
        StageSim,
        Trajectory,
    )
    from machine.stage_params import preset

    force = SEED000_FORCE if preset_name == "seed000" else SEED001_FORCE
    if no_force:
        force = CuttingForce(offset=0.0, amplitudes=(0.0,), frequencies=(100.0,))
    traj = Trajectory(
        speed=case.speed, half_period=case.half_period, dwell=case.dwell, levels=case.levels
    )
    cfg = StageConfig(
        params=preset(preset_name),
        force=force,
        trajectory=traj,
        effects=case.effects,
        current_noise=case.current_noise,
    )
    sim = StageSim(cfg, seed=0 if seed is None else seed)
    if weight:
        sim.set_weight(True)
    block = 2500
    n_total = int(round(seconds / cfg.sample_time))
    cols: dict[str, list[np.ndarray]] = {
        k: [] for k in ("t", "tau_m", "i_m", "q_m", "q_l", "f_ext")
    }
    done = 0
    while done < n_total:
        n = min(block, n_total - done)
        m, _ = sim.step(n)
        for k in cols:
            cols[k].append(getattr(m, k))
        done += n
        if on_block is not None:
            on_block(n)
    sidecar = {
        "sample_time": cfg.sample_time,
        "units": {"effort": "N m", "position": "rad", "current": "A"},
        "kind": "two_inertia",
        "nominal": cfg.params.as_dict(),
        "encoder_resolution": cfg.encoder_resolution,
        "source": f"cutwatch simulate --preset {preset_name}",
        "trajectory": {
            "speed": case.speed,
            "half_period": case.half_period,
            "dwell": case.dwell,
            "levels": list(case.levels),
        },
    }
    enabled = sorted(case.effects.enabled)
    params_of = {
        "offset": ("offset",),
        "coulomb_asymmetry": ("coulomb_asymmetry",),
        "stribeck": ("stribeck", "stribeck_velocity"),
        "position_periodic": ("position_periodic", "position_period", "position_phase"),
        "torque_ripple": ("torque_ripple", "torque_ripple_order", "torque_ripple_phase"),
        "backlash": ("backlash",),
    }
    truth = {
        "params": sim.config.true_params.as_dict(),
        "effects": enabled,
        "effect_parameters": {
            k: getattr(case.effects, k) for e in enabled for k in params_of.get(e, (e,))
        },
        "weight": bool(weight),
        "current_noise": case.current_noise,
        "seed": seed,
    }
    return {k: np.concatenate(v) for k, v in cols.items()}, sidecar, truth


def stribeck_band(truth: dict[str, Any]) -> float:
    """Upper load speed of the band where the simulator's Stribeck term acts (2 v_s)."""
    v = truth.get("effect_parameters", {}).get("stribeck_velocity", 3.0)
    return 2.0 * float(v) if math.isfinite(float(v)) else 6.0
