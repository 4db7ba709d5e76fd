"""Every estimator's state saved and restored (common.state_io): a state written to a
file, read back and stepped on gives what the original state gives, bit for bit."""

from __future__ import annotations

import json
import math
import re
from collections.abc import Callable
from dataclasses import fields, is_dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from common.state_io import StateFormatError, load_state, save_state
from estimators.dfo import Dfo, DfoParams
from estimators.force_observer import ObserverParams, TorsionEstimator
from estimators.imbdo import Imbdo, ImbdoParams
from estimators.observer_effects import EffectsParams, ObserverEffect, ObserverEffects
from estimators.rls import IdentifierParams, LoadIdentifier
from estimators.segment_id import SegmentIdentifier, SegmentIdentifierParams
from estimators.ud_rls import ForgettingRLS, ForgettingRLSParams
from estimators.wear.monitor import ToolLifeMonitor, ToolLifeParams
from machine.stage import StageConfig, StageSim
from machine.stage_params import preset

N = 2500  # 1 s at 2.5 kHz


def _same(a: Any, b: Any) -> bool:
    if is_dataclass(a):
        return type(a) is type(b) and all(
            _same(getattr(a, f.name), getattr(b, f.name)) for f in fields(a)
        )
    if isinstance(a, np.ndarray):
        return bool(np.array_equal(a, b, equal_nan=a.dtype.kind in "fc"))
    if isinstance(a, float):
        return a == b or (np.isnan(a) and np.isnan(b))
    return bool(a == b)


def _stage() -> tuple[Any, Any]:
    p = preset("seed000")
    sim = StageSim(StageConfig(params=p), seed=3)
    m, _ = sim.step(2 * N)
    front = TorsionEstimator(ObserverParams(J_M=p.J_M, B_M=p.B_M, F_CM=p.F_CM, K=p.K))
    _, rec = front.step(front.initial_state(), m.tau_m, m.q_m, m.q_l)
    return m, rec


M, REC = _stage()
P0 = preset("seed000")
H1, H2 = slice(0, N), slice(N, 2 * N)


def _front() -> tuple[Any, Any, Callable[[Any, slice], Any]]:
    est = TorsionEstimator(ObserverParams(J_M=P0.J_M, B_M=P0.B_M, F_CM=P0.F_CM, K=P0.K))
    return est, est.initial_state(), lambda s, h: est.step(s, M.tau_m[h], M.q_m[h], M.q_l[h])


def _ident(switching: bool) -> tuple[Any, Any, Callable[[Any, slice], Any]]:
    est = LoadIdentifier(IdentifierParams(), switching=switching)
    r = REC
    return (
        est,
        est.initial_state(P0.J_L, P0.B_L, P0.F_CL),
        lambda s, h: est.step(s, r.t_s[h], r.acc_l[h], r.vel_l[h], r.sgn_l[h], r.omega_l[h]),
    )


def _segment() -> tuple[Any, Any, Callable[[Any, slice], Any]]:
    est = SegmentIdentifier(
        SegmentIdentifierParams(nominal=(P0.J_L, P0.B_L, P0.F_CL), sample_time=4e-4)
    )
    r = REC
    return (
        est,
        est.initial_state(),
        lambda s, h: est.step(s, M.t[h], r.t_s[h], r.acc_l[h], r.vel_l[h], r.sgn_l[h]),
    )


def _effects() -> tuple[Any, Any, Callable[[Any, slice], Any]]:
    fx = (ObserverEffect("offset", {}, (0.3,)), ObserverEffect("stribeck", {"v_s": 0.5}, (0.1,)))
    est = ObserverEffects(EffectsParams(fx, 4e-4))
    return (
        est,
        est.initial_state(),
        lambda s, h: est.step(s, REC.alpha[h], M.t[h], M.q_m[h], M.q_l[h], M.tau_m[h]),
    )


def _dfo() -> tuple[Any, Any, Callable[[Any, slice], Any]]:
    est = Dfo(
        DfoParams(
            frequencies=(100.0, 200.0),
            sample_time=4e-4,
            channel_num=(1571.0,),
            channel_den=(1.0, 1571.0),
            include_offset=True,
        )
    )
    return est, est.initial_state(), lambda s, h: est.step(s, REC.t_s[h])


def _imbdo() -> tuple[Any, Any, Callable[[Any, slice], Any]]:
    est = Imbdo(ImbdoParams(78020.0, 163.0, 193.3, 1e-3, model_delay=0.0012))
    return est, est.initial_state(), lambda s, h: est.step(s, M.q_m[h], M.tau_m[h])


def _rls() -> tuple[Any, Any, Callable[[Any, slice], Any]]:
    est = ForgettingRLS(ForgettingRLSParams(n=2))
    phi = np.column_stack([REC.acc_l, REC.vel_l])
    return est, est.initial_state(), lambda s, h: est.step(s, phi[h], REC.t_s[h])


def _monitor() -> tuple[Any, Any, Callable[[Any, slice], Any]]:
    est = ToolLifeMonitor(ToolLifeParams(force_per_flank_wear=900.0))
    t = np.arange(1, 41, dtype=np.float64)
    f = 400.0 + 3.0 * t + np.sin(t)
    halves = {0: slice(0, 20), N: slice(20, 40)}
    return (
        est,
        est.initial_state(),
        lambda s, h: est.step(s, t[halves[h.start]], f[halves[h.start]], np.full(20, 0.1)),
    )


CASES: dict[str, Callable[[], tuple[Any, Any, Callable[[Any, slice], Any]]]] = {
    "torsion front end (seed 000)": _front,
    "RLS identifier (seed 000)": lambda: _ident(False),
    "switching RLS (seed 001)": lambda: _ident(True),
    "segment identifier": _segment,
    "observer effects": _effects,
    "DFO (seed 002)": _dfo,
    "IMBDO (seed 002)": _imbdo,
    "forgetting RLS (seed 004)": _rls,
    "tool-life monitor (seed 004)": _monitor,
}


@pytest.mark.parametrize("name", list(CASES))
def test_a_saved_state_continues_as_the_original(tmp_path: Path, name: str) -> None:
    _, s0, step = CASES[name]()
    s1, _ = step(s0, H1)  # a state with history
    save_state(tmp_path / "s.npz", s1, kind=name, version=1)
    back, _ = load_state(tmp_path / "s.npz", kind=name, version=1)
    assert _same(s1, back)
    (sa, ra), (sb, rb) = step(s1, H2), step(back, H2)
    assert _same(ra, rb) and _same(sa, sb)


def test_another_kind_or_version_is_refused(tmp_path: Path) -> None:
    _, s0, _ = _front()
    save_state(tmp_path / "s.npz", s0, kind="front", version=2)
    with pytest.raises(StateFormatError, match=r"expected kind 'rls', found 'front'"):
        load_state(tmp_path / "s.npz", kind="rls", version=2)
    with pytest.raises(StateFormatError, match=r"expected front version 3, found 2"):
        load_state(tmp_path / "s.npz", kind="front", version=3)


def test_values_outside_the_codec_are_refused_by_path(tmp_path: Path) -> None:
    with pytest.raises(StateFormatError, match=r"state\.x\[1\]: expected a value of cutwatch"):
        save_state(tmp_path / "s.npz", {"x": (1.0, object())}, kind="k", version=1)


def test_a_state_written_before_the_stage_params_moved_reads_as_now() -> None:
    # machine/params.py became machine/stage_params.py (issue 34, names by meaning): the
    # default scenario's checkpoint names its stage's parameters machine.params:StageParams
    # (common.state_io.MOVED), and must still load after the upgrade
    from common.state_io import decode, encode
    from machine.stage_params import PRESETS, StageParams

    params = PRESETS[sorted(PRESETS)[0]]
    tree, arrays = encode({"config": {"params": params}})
    text = json.dumps(tree)
    assert '"machine.stage_params:StageParams"' in text
    old = json.loads(text.replace("machine.stage_params:", "machine.params:"))
    back = decode(old, arrays)
    assert type(back["config"]["params"]) is StageParams
    assert back["config"]["params"] == params


def test_a_state_written_before_the_wear_models_moved_reads_as_now() -> None:
    # estimators/wear_monitor.py became estimators/wear/monitor.py and
    # estimators/centre_wear.py estimators/wear/centre.py (issue 34 item 4, estimators
    # grouped by topic): a checkpoint written before names the old modules
    # (common.state_io.MOVED) and must still load after the upgrade
    from common.state_io import decode, encode
    from estimators.wear.centre import CentreWear, CentreWearState
    from estimators.wear.monitor import ToolLifeState

    est, s0, advance = _monitor()
    saved = {
        "params": est.params,
        "tool": advance(s0, slice(0, 20))[0],
        "centre": CentreWear().initial_state(),
    }
    tree, arrays = encode(saved)
    text = json.dumps(tree)
    assert '"estimators.wear.monitor:ToolLifeState"' in text
    assert '"estimators.wear.centre:CentreWearState"' in text
    old = text.replace("estimators.wear.monitor:", "estimators.wear_monitor:")
    old = old.replace("estimators.wear.centre:", "estimators.centre_wear:")
    assert "estimators.wear." not in old
    back = decode(json.loads(old), arrays)
    assert type(back["params"]) is ToolLifeParams
    assert type(back["tool"]) is ToolLifeState
    assert type(back["centre"]) is CentreWearState
    again, again_arrays = encode(back)
    assert json.dumps(again) == text
    assert sorted(again_arrays) == sorted(arrays)
    for k, a in arrays.items():
        np.testing.assert_array_equal(again_arrays[k], a)


def test_a_state_written_before_the_residual_loop_moved_reads_as_now() -> None:
    # estimators/residual_engine.py became estimators/residual/engine.py and
    # estimators/residual.py estimators/residual/rigid.py (issue 34 item 4): a state naming
    # the old modules (common.state_io.MOVED) reads as now
    from common.state_io import decode, encode
    from estimators.residual.engine import ResidualParams

    params = ResidualParams()
    tree, arrays = encode({"residual": params})
    text = json.dumps(tree)
    assert '"estimators.residual.engine:ResidualParams"' in text
    named = set(re.findall(r"estimators\.residual\.(\w+):", text))
    assert "engine" in named
    old = re.sub(
        r"estimators\.residual\.(\w+):",
        lambda m: "estimators.residual:" if m[1] == "rigid" else f"estimators.residual_{m[1]}:",
        text,
    )
    assert "estimators.residual." not in old
    back = decode(json.loads(old), arrays)
    assert type(back["residual"]) is ResidualParams
    assert back["residual"] == params


def test_a_state_written_before_the_process_monitors_moved_reads_as_now() -> None:
    # estimators/process_monitor.py became estimators/monitoring/process.py and
    # estimators/spindle_power.py estimators/monitoring/spindle_power.py (issue 34 item 4):
    # the live process and spindle parts' checkpoints named the old modules
    # (common.state_io.MOVED) and must still load after the upgrade
    from common.state_io import decode, encode
    from estimators.monitoring.process import MonitorParams, ProcessMonitor
    from estimators.monitoring.spindle_power import IdlePower, IdlePowerParams, IdlePowerState

    idle = IdlePower(IdlePowerParams(sample_time=0.01))
    saved = {"monitor": ProcessMonitor(MonitorParams()), "idle": idle, "s": idle.initial_state()}
    tree, arrays = encode(saved)
    text = json.dumps(tree)
    assert '"estimators.monitoring.process:ProcessMonitor"' in text
    assert '"estimators.monitoring.spindle_power:IdlePowerState"' in text
    old = text.replace("estimators.monitoring.process:", "estimators.process_monitor:")
    old = old.replace("estimators.monitoring.spindle_power:", "estimators.spindle_power:")
    assert "estimators.monitoring." not in old
    back = decode(json.loads(old), arrays)
    assert type(back["monitor"]) is ProcessMonitor
    assert type(back["idle"]) is IdlePower
    assert type(back["s"]) is IdlePowerState
    assert json.dumps(encode(back)[0]) == text


def test_a_state_written_before_the_stability_lobes_moved_reads_as_now() -> None:
    # estimators/lobes_sd.py became estimators/chatter/sd.py and estimators/lobes_zoa.py
    # estimators/chatter/zoa.py (issue 34 item 4): a state naming the old modules
    # (common.state_io.MOVED) reads as now
    from common.state_io import decode, encode
    from estimators.chatter.sd import Multiplier
    from estimators.chatter.zoa import ZoaLobe

    saved = {
        "m": Multiplier(modulus=1.2, angle=math.pi),
        "lobe": ZoaLobe(
            k=0, rpm=np.array([9000.0]), depth=np.array([1e-3]), freq_hz=np.array([950.0])
        ),
    }
    tree, arrays = encode(saved)
    text = json.dumps(tree)
    assert '"estimators.chatter.sd:Multiplier"' in text
    assert '"estimators.chatter.zoa:ZoaLobe"' in text
    old = text.replace("estimators.chatter.sd:", "estimators.lobes_sd:")
    old = old.replace("estimators.chatter.zoa:", "estimators.lobes_zoa:")
    assert "estimators.chatter." not in old
    back = decode(json.loads(old), arrays)
    assert back["m"] == saved["m"] and back["m"].kind == "flip"
    assert type(back["lobe"]) is ZoaLobe
    np.testing.assert_array_equal(back["lobe"].depth, saved["lobe"].depth)
