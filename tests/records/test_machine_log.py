"""Logs of a described machine: every column its signals name, checked by the description;
older one-axis logs read as one axis."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from server.errors import LogFormatError
from server.records.measured_log import load_log, write_log

ROOT = Path(__file__).resolve().parents[2]
DATA = ROOT / ".." / "shared" / "data"
MACHINE = {
    "sample_time": 0.002,
    "axes": {
        "X": {"kind": "rigid", "signals": {"q_m": "xq", "i_m": "xi", "qd_m": "xv"},
              "units": {"position": "m"}},
        "Y": {"kind": "two_inertia", "signals": {"q_m": "yq", "q_l": "ys", "tau_m": "yf"},
              "units": {"position": "m", "effort": "N"}},
    },
    "spindle": {"signals": {"speed": "srpm", "load": "sload"}},
    "identities": {"tool": "tool_no", "line": "nline"},
}  # fmt: skip


def _columns(n: int = 200) -> dict[str, np.ndarray]:
    k = np.arange(n, dtype=float)
    return {
        "xq": k * 1e-5, "xi": np.sin(k), "xv": np.full(n, 5e-3),
        "yq": -k * 1e-5, "ys": -k * 1e-5, "yf": np.cos(k),
        "srpm": np.full(n, 9000.0), "sload": np.where(k < 50, np.nan, 30.0),
        "tool_no": np.full(n, 4.0), "nline": 10 + (k // 40),
        "volts": np.full(n, 560.0),  # a column the machine does not name
    }  # fmt: skip


def test_a_described_log_keeps_every_named_column(tmp_path: Path) -> None:
    p = tmp_path / "mc.csv"
    write_log(p, _columns(), MACHINE)
    log = load_log(p)
    assert log.description is not None and log.machine.axis_names == ("X", "Y")
    assert log.sample_time == pytest.approx(0.002) and log.n == 200
    np.testing.assert_allclose(log["t"], np.arange(200) * 0.002)  # time from sample_time
    assert set(log.columns) == {"t", "xq", "xi", "xv", "yq", "ys", "yf", "srpm", "sload"} | {
        "tool_no",
        "nline",
    }
    assert np.isnan(log["sload"][:50]).all()  # an optional signal may be unknown
    assert log.kind is None  # two axes of two kinds


@pytest.mark.parametrize(
    ("change", "match"),
    [
        (("drop", "ys"), r"missing column\(s\) 'ys' \(Y.q_l\), which the machine description"),
        (("nan", "xq"), r"column 'xq', row 4: expected a finite value"),
        (("set", "nline", 2.5), r"column 'nline', row 4: expected a whole number"),
    ],
)
def test_a_described_log_that_breaks_its_machine_is_named(
    tmp_path: Path, change: tuple, match: str
) -> None:
    cols = _columns()
    if change[0] == "drop":
        del cols[change[1]]
    elif change[0] == "nan":
        cols[change[1]][3] = np.nan
    else:
        cols[change[1]][3] = change[2]
    p = tmp_path / "bad.csv"
    write_log(p, cols, MACHINE)
    with pytest.raises(LogFormatError, match=match):
        load_log(p)


def test_a_broken_sidecar_names_the_file_and_the_key(tmp_path: Path) -> None:
    p = tmp_path / "s.csv"
    bad = json.loads(json.dumps(MACHINE))
    bad["axes"]["X"]["units"]["position"] = "mm"
    write_log(p, _columns(), bad)
    with pytest.raises(LogFormatError, match=r"s.csv: sidecar: .*key 'axes.X.units.position'"):
        load_log(p)


def test_an_older_log_is_one_axis(tmp_path: Path) -> None:
    p = tmp_path / "old.csv"
    t = np.arange(100) * 1e-3
    write_log(p, {"t": t, "tau_m": np.sin(t), "q_m": t, "line": np.full(100, 7.0)},
              {"units": {"effort": "N", "position": "m"}, "kind": "rigid"})  # fmt: skip
    log = load_log(p)
    assert log.description is None
    m = log.machine
    assert m.axis_names == ("axis",) and m.axes[0].signals == {"q_m": "q_m", "tau_m": "tau_m"}
    assert m.identities == {"line": "line"} and m.sample_time == pytest.approx(1e-3)


@pytest.mark.skipif(not (DATA / "cnc-mill").is_dir(), reason="shared data not present")
def test_a_real_cnc_export_as_one_machine() -> None:
    """experiment_01 of the cnc-mill set: X, Y, Z, the spindle and the program line."""
    from server.records.measured_log import load_meta

    meta = load_meta(ROOT / "docs" / "machines" / "cnc-mill.json")  # maps inside
    log = load_log(DATA / "cnc-mill" / "experiment_01.csv", meta=meta)
    m = log.machine
    assert m.axis_names == ("X", "Y", "Z") and m.rate_hz == pytest.approx(10.0)
    assert log.n == 1055
    assert float(np.nanmax(log["X_v"])) > 5e-3  # mm/s mapped to m/s
    assert set(np.unique(log["M1_sequence_number"])) >= {0.0, 65.0}


def test_sidecar_maps_are_applied_before_the_command_lines(tmp_path: Path) -> None:
    p = tmp_path / "m.csv"
    n = 20
    cols = _columns(n)
    cols["xq_mm"] = cols.pop("xq") * 1e3
    write_log(p, cols, {**MACHINE, "maps": ["xq=xq_mm*0.001"]})
    np.testing.assert_allclose(load_log(p)["xq"], np.arange(n) * 1e-5)
    np.testing.assert_allclose(load_log(p, maps=["xq=xq_mm*2"])["xq"], np.arange(n) * 2e-2)
    write_log(p, cols, {**MACHINE, "maps": ["xq=xq_mm*0.001", "xq=2*xq_mm"]})
    with pytest.raises(LogFormatError, match=r"sidecar 'maps\[1\]': --map 'xq=2\*xq_mm'"):
        load_log(p)


def test_a_recording_keeps_every_column_and_reads_back_as_the_same_machine(
    tmp_path: Path,
) -> None:
    from server.records.recorder import Recorder

    cols = _columns(200)
    cols.pop("volts")
    t = np.arange(200) * 0.002
    rec = Recorder(tmp_path / "rec.csv", {**MACHINE, "program": "O7"})
    for a in range(0, 200, 50):
        rec.append({"t": t[a : a + 50], **{k: v[a : a + 50] for k, v in cols.items()}})
    assert rec.close()["samples"] == 200
    log = load_log(tmp_path / "rec.csv")
    assert log.machine == load_log_machine(MACHINE)
    for k, v in cols.items():
        np.testing.assert_array_equal(log[k], v)  # NaN kept as NaN, values exact
    assert log.sidecar["program"] == "O7" and log.sidecar["recording"]["samples"] == 200


def load_log_machine(d: dict) -> object:
    from common.machine_description import from_dict

    return from_dict(d)


def test_a_recording_refuses_a_name_no_csv_header_can_hold(tmp_path: Path) -> None:
    from server.errors import CutwatchError
    from server.records.recorder import Recorder

    rec = Recorder(tmp_path / "r.csv", MACHINE)
    with pytest.raises(CutwatchError, match="column name 'a,b' cannot be a CSV header"):
        rec.append({"t": np.zeros(2), "a,b": np.zeros(2)})
    rec.close()
