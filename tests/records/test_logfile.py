"""Measured-log reading and writing (docs/design.md, "Measured log"): checks and error messages."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import scipy.io
from hypothesis import given, settings
from hypothesis import strategies as st

from server.errors import LogFormatError
from server.records.measured_log import ColumnMap, load_log, load_meta, parse_map, write_log

UNITS = {"units": {"effort": "N", "position": "m"}, "kind": "rigid"}
EMPS = Path(__file__).resolve().parents[3] / "shared" / "data" / "emps" / "DATA_EMPS.mat"


def _cols(n: int = 50, ts: float = 1e-3) -> dict[str, np.ndarray]:
    t = np.arange(n) * ts
    return {"t": t, "tau_m": np.sin(t * 30.0), "q_m": np.cos(t * 7.0)}


def _write_raw(path: Path, text: str, sidecar: dict | None = UNITS) -> Path:
    path.write_text(text)
    if sidecar is not None:
        path.with_suffix(".json").write_text(json.dumps(sidecar))
    return path


def test_write_then_load_round_trip(tmp_path: Path) -> None:
    cols = _cols()
    write_log(tmp_path / "run.csv", cols, {**UNITS, "sample_time": 1e-3, "nominal": {"M": 2.0}})
    log = load_log(tmp_path / "run.csv")
    assert log.n == 50
    assert log.sample_time == pytest.approx(1e-3)
    assert log.kind == "rigid"
    assert log.nominal == {"M": 2.0}
    for k, v in cols.items():
        np.testing.assert_array_equal(log[k], v)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["run.csv", "run.json"]


def test_write_log_refuses_ragged_columns_and_leaves_nothing(tmp_path: Path) -> None:
    cols = _cols()
    cols["q_m"] = cols["q_m"][:-1]
    with pytest.raises(LogFormatError, match="column 'q_m': expected a 1-D array of 50"):
        write_log(tmp_path / "run.csv", cols, UNITS)
    assert list(tmp_path.iterdir()) == []


def test_write_log_failure_midway_leaves_no_partial_output(tmp_path: Path) -> None:
    class NotJson:
        pass

    with pytest.raises(TypeError):
        write_log(tmp_path / "run.csv", _cols(), {**UNITS, "bad": NotJson()})
    assert list(tmp_path.iterdir()) == []


def test_current_effort_is_scaled_by_kt(tmp_path: Path) -> None:
    n = 20
    t = np.arange(n) * 1e-3
    write_log(
        tmp_path / "c.csv",
        {"t": t, "i_m": np.full(n, 2.0), "q_m": t},
        {"units": {"effort": "A", "position": "rad"}, "nominal": {"K_t": 0.5}},
    )
    log = load_log(tmp_path / "c.csv")
    np.testing.assert_allclose(log["tau_m"], 1.0)
    assert log.units["effort"] == "N m"


def test_current_without_kt_is_refused(tmp_path: Path) -> None:
    t = np.arange(10) * 1e-3
    write_log(
        tmp_path / "c.csv",
        {"t": t, "i_m": t, "q_m": t},
        {"units": {"effort": "A", "position": "rad"}},
    )
    with pytest.raises(LogFormatError, match=r"expected nominal.K_t"):
        load_log(tmp_path / "c.csv")


def test_jitter_is_tolerated(tmp_path: Path) -> None:
    cols = _cols(200)
    rng = np.random.default_rng(1)
    cols["t"] = cols["t"] + rng.uniform(-1e-5, 1e-5, 200)
    write_log(tmp_path / "j.csv", cols, UNITS)
    assert load_log(tmp_path / "j.csv").sample_time == pytest.approx(1e-3, rel=1e-2)


def test_gap_is_refused_naming_the_row(tmp_path: Path) -> None:
    cols = _cols(30)
    cols = {k: np.delete(v, [10, 11]) for k, v in cols.items()}
    write_log(tmp_path / "g.csv", cols, UNITS)
    with pytest.raises(LogFormatError, match=r"g.csv: column 't', row 11: gap of 0.003 s"):
        load_log(tmp_path / "g.csv")


def test_non_monotonic_time_is_refused(tmp_path: Path) -> None:
    cols = _cols(30)
    cols["t"][5] = cols["t"][4]
    write_log(tmp_path / "m.csv", cols, UNITS)
    with pytest.raises(LogFormatError, match="column 't', row 6: time not increasing"):
        load_log(tmp_path / "m.csv")


def test_non_uniform_time_is_refused(tmp_path: Path) -> None:
    cols = _cols(30)
    cols["t"][10:] += 3e-4
    write_log(tmp_path / "u.csv", cols, UNITS)
    with pytest.raises(LogFormatError, match=r"row 11: interval 0.0013 s \(expected 0.001 s"):
        load_log(tmp_path / "u.csv")


def test_declared_sample_time_must_match(tmp_path: Path) -> None:
    write_log(tmp_path / "s.csv", _cols(), {**UNITS, "sample_time": 0.01})
    with pytest.raises(LogFormatError, match=r"sample_time = 0.01 s, but column 't'"):
        load_log(tmp_path / "s.csv")


@pytest.mark.parametrize("cell", ["nan", "inf", "-inf"])
def test_non_finite_values_are_refused(tmp_path: Path, cell: str) -> None:
    text = "t,tau_m,q_m\n0,1,2\n0.001,1,2\n0.002," + cell + ",2\n0.003,1,2\n"
    _write_raw(tmp_path / "n.csv", text)
    with pytest.raises(LogFormatError, match="column 'tau_m', row 3: expected a finite value"):
        load_log(tmp_path / "n.csv")


def test_non_numeric_cell_is_refused(tmp_path: Path) -> None:
    text = "t,tau_m,q_m\n0,1,2\n0.001,abc,2\n"
    _write_raw(tmp_path / "x.csv", text)
    with pytest.raises(
        LogFormatError, match=r"row 2 \(line 3\), column 'tau_m': expected a number, found 'abc'"
    ):
        load_log(tmp_path / "x.csv")


def test_wrong_cell_count_is_refused(tmp_path: Path) -> None:
    _write_raw(tmp_path / "w.csv", "t,tau_m,q_m\n0,1,2\n0.001,1\n")
    with pytest.raises(LogFormatError, match=r"row 2 .*expected 3 cells"):
        load_log(tmp_path / "w.csv")


def test_missing_column_names_missing_and_found(tmp_path: Path) -> None:
    _write_raw(tmp_path / "c.csv", "t,torque,q_m\n0,1,2\n0.001,1,2\n")
    with pytest.raises(LogFormatError, match=r"missing column.* tau_m; found q_m, t, torque"):
        load_log(tmp_path / "c.csv")


def test_map_renames_and_scales(tmp_path: Path) -> None:
    _write_raw(tmp_path / "c.csv", "time,torque,pos\n0,1,2\n0.001,2,3\n0.002,3,4\n")
    log = load_log(tmp_path / "c.csv", maps=["t=time", "tau_m=torque*2+0.5", "q_m=pos*1e-3"])
    np.testing.assert_allclose(log["tau_m"], [2.5, 4.5, 6.5])
    np.testing.assert_allclose(log["q_m"], [2e-3, 3e-3, 4e-3])


def test_map_of_missing_source_names_the_columns(tmp_path: Path) -> None:
    _write_raw(tmp_path / "c.csv", "t,torque,q_m\n0,1,2\n0.001,2,3\n")
    with pytest.raises(LogFormatError, match="column 'torq' does not exist; found q_m, t, torque"):
        load_log(tmp_path / "c.csv", maps=["tau_m=torq"])


@pytest.mark.parametrize(
    "text",
    [
        "tau_m",
        "tau_m=vir*",
        "tau_m=vir**2",
        "tau_m=__import__('os')",
        "tau_m=vir+1*2",
        "tau_m=vir*2+x",
        "1x=vir",
        "tau_m=vir;q",
    ],
)
def test_bad_map_expressions_are_refused(text: str) -> None:
    with pytest.raises(LogFormatError, match="expected COL=name, COL=name\\*scale"):
        parse_map(text)


@given(
    scale=st.floats(-1e6, 1e6, allow_nan=False),
    offset=st.floats(0, 1e6, allow_nan=False),
    neg=st.booleans(),
)
@settings(max_examples=60, deadline=None)
def test_map_parse_round_trips_numbers(scale: float, offset: float, neg: bool) -> None:
    sign = "-" if neg else "+"
    m = parse_map(f"tau_m=vir*{scale!r}{sign}{offset!r}")
    assert m == ColumnMap("tau_m", "vir", scale, -offset if neg else offset)


def test_units_must_be_declared(tmp_path: Path) -> None:
    _write_raw(tmp_path / "c.csv", "t,tau_m,q_m\n0,1,2\n0.001,2,3\n", sidecar=None)
    with pytest.raises(LogFormatError, match="units not declared"):
        load_log(tmp_path / "c.csv")
    log = load_log(tmp_path / "c.csv", meta={"units": {"effort": "N", "position": "m"}})
    assert log.n == 2


def test_unknown_unit_and_kind_are_refused(tmp_path: Path) -> None:
    _write_raw(
        tmp_path / "c.csv",
        "t,tau_m,q_m\n0,1,2\n0.001,2,3\n",
        sidecar={"units": {"effort": "kgf", "position": "m"}},
    )
    with pytest.raises(LogFormatError, match=r"units.effort = 'kgf': expected one of"):
        load_log(tmp_path / "c.csv")
    with pytest.raises(LogFormatError, match="kind 'three_mass': expected one of rigid"):
        load_log(
            tmp_path / "c.csv", meta={"units": {"effort": "N", "position": "m"}}, kind="three_mass"
        )


def test_bad_sidecar_and_meta(tmp_path: Path) -> None:
    p = tmp_path / "c.csv"
    p.write_text("t,tau_m,q_m\n0,1,2\n0.001,2,3\n")
    p.with_suffix(".json").write_text("{not json")
    with pytest.raises(LogFormatError, match=r"c.json: not valid JSON"):
        load_log(p)
    with pytest.raises(LogFormatError, match="--meta: not valid JSON"):
        load_meta("{oops")
    with pytest.raises(LogFormatError, match="no such file"):
        load_meta(str(tmp_path / "absent.json"))
    assert load_meta('{"kind": "rigid"}') == {"kind": "rigid"}


def test_missing_file_and_unknown_suffix(tmp_path: Path) -> None:
    with pytest.raises(LogFormatError, match="no such file"):
        load_log(tmp_path / "absent.csv")
    (tmp_path / "a.xlsx").write_text("x")
    with pytest.raises(LogFormatError, match=r"unknown file type '.xlsx'"):
        load_log(tmp_path / "a.xlsx")


def test_mat_file_with_map_and_scalar_scale(tmp_path: Path) -> None:
    n = 40
    p = tmp_path / "m.mat"
    scipy.io.savemat(
        p,
        {
            "time": (np.arange(n) * 1e-3)[:, None],
            "u": np.ones((n, 1)),
            "pos": np.zeros((1, n)),
            "gain": np.array([[3.0]]),
        },
    )
    log = load_log(p, meta=UNITS, maps=["t=time", "tau_m=u*gain", "q_m=pos"])
    np.testing.assert_allclose(log["tau_m"], 3.0)
    with pytest.raises(LogFormatError, match="variable 'vir' does not exist; found gain, pos"):
        load_log(p, meta=UNITS, maps=["t=time", "tau_m=vir*gain", "q_m=pos"])
    with pytest.raises(LogFormatError, match="scale variable 'gtau' does not exist"):
        load_log(p, meta=UNITS, maps=["t=time", "tau_m=u*gtau", "q_m=pos"])


def test_not_a_mat_file(tmp_path: Path) -> None:
    p = tmp_path / "bad.mat"
    p.write_bytes(b"this is not matlab")
    with pytest.raises(LogFormatError, match=r"bad.mat: not a readable MATLAB"):
        load_log(p, meta=UNITS)


@pytest.mark.skipif(not EMPS.exists(), reason="EMPS data not present")
def test_emps_file_loads_through_the_map() -> None:
    log = load_log(EMPS, meta=UNITS, maps=["tau_m=vir*gtau", "q_m=qm"])
    assert log.n == 24841
    assert log.sample_time == pytest.approx(1e-3, rel=1e-4)


def test_identity_columns_are_kept_and_checked(tmp_path: Path) -> None:
    from server.errors import LogFormatError

    cols = _cols()
    n = len(cols["t"])
    cols = {
        **cols,
        "tool": np.where(np.arange(n) < n // 2, 1.0, 2.0),
        "line": np.full(n, 20.0),
        "override": np.full(n, 1.1),
    }
    write_log(tmp_path / "id.csv", cols, {**UNITS, "program": "O1001"})
    log = load_log(tmp_path / "id.csv")
    np.testing.assert_array_equal(log["tool"], cols["tool"])
    assert log.sidecar["program"] == "O1001"
    cols["line"][3] = 2.5
    write_log(tmp_path / "bad.csv", cols, UNITS)
    with pytest.raises(LogFormatError, match=r"column 'line', row 4: expected a whole number"):
        load_log(tmp_path / "bad.csv")
