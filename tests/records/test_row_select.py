"""Reading exports as they come (issue 18 item 2): text columns, row selection, time from
``sample_time``, effort in A, line ends; every refusal names file, column, row, expected
and found; the rows each rule leaves out are counted."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from server.errors import LogFormatError
from server.records.measured_log import load_log
from server.records.row_select import RowSelection, parse_condition

META = {"sample_time": 0.1, "units": {"effort": "A", "position": "m"}}
MAPS = ["q_m=Xpos*0.001", "tau_m=Xcur"]


def _export(path: Path, eol: str = "\n", rows: list[str] | None = None) -> Path:
    """A small CNC-like export: no time column, a text label with spaces, an empty cell."""
    header = "Xpos,Xvel,Xcur,Spindle,Note,Machining_Process"
    if rows is None:
        rows = []
        for i in range(12):
            label = "Prep" if i < 3 else ("Layer 1 Up" if i < 8 else "Repositioning")
            spindle = 0 if i < 3 else 53.3
            note = "" if i == 5 else f"{i}.5"
            rows.append(f"{150 + i},{10.0 - i},{0.5 * i - 1},{spindle},{note},{label}")
    path.write_bytes((eol.join([header, *rows]) + eol).encode())
    return path


def _load(path: Path, **kw: object) -> object:
    return load_log(path, meta=META, maps=MAPS, current_ok=True, **kw)  # type: ignore[arg-type]


def test_text_columns_are_ignored_and_time_comes_from_sample_time(tmp_path: Path) -> None:
    log = _load(_export(tmp_path / "e.csv"))
    assert log.n == 12 and log.n_read == 12
    np.testing.assert_allclose(log["t"], np.arange(12) * 0.1)
    np.testing.assert_allclose(log["q_m"], (150 + np.arange(12)) * 0.001)
    assert log.units["effort"] == "A"  # no K_t: kept in A
    assert set(log.columns) == {"t", "tau_m", "q_m"}
    assert list(log.segments) == [0]


@pytest.mark.parametrize("eol", ["\r", "\r\n"])
def test_cr_and_crlf_line_ends_read_as_lf(tmp_path: Path, eol: str) -> None:
    ref = _load(_export(tmp_path / "lf.csv", "\n"))
    other = _load(_export(tmp_path / "x.csv", eol))
    for c in ref.columns:
        np.testing.assert_array_equal(ref[c], other[c])


def test_current_without_kt_is_still_refused_where_a_force_is_needed(tmp_path: Path) -> None:
    p = _export(tmp_path / "e.csv")
    with pytest.raises(LogFormatError, match=r"e.csv: units.effort = 'A'.*expected nominal.K_t"):
        load_log(p, meta=META, maps=MAPS)
    log = load_log(p, meta={**META, "nominal": {"K_t": 2.0}}, maps=MAPS)
    assert log.units["effort"] == "N m"
    np.testing.assert_allclose(log["tau_m"], 2.0 * (0.5 * np.arange(12) - 1))


def test_a_mapped_text_column_is_refused_naming_row_column_and_cell(tmp_path: Path) -> None:
    p = _export(tmp_path / "e.csv")
    with pytest.raises(
        LogFormatError,
        match=r"e.csv: row 6 \(line 7\), column 'Note': expected a number, found ''",
    ):
        load_log(p, meta=META, maps=[*MAPS, "f_ext=Note"], current_ok=True)
    with pytest.raises(
        LogFormatError,
        match=r"row 1 \(line 2\), column 'Machining_Process': "
        r"expected a number, found 'Prep'",
    ):
        load_log(p, meta=META, maps=["q_m=Machining_Process", "tau_m=Xcur"], current_ok=True)


def test_no_time_column_and_no_sample_time_names_both(tmp_path: Path) -> None:
    p = _export(tmp_path / "e.csv")
    with pytest.raises(LogFormatError, match=r"missing column\(s\) t; .*or declare sample_time"):
        load_log(p, meta={"units": META["units"]}, maps=MAPS, current_ok=True)
    with pytest.raises(LogFormatError, match=r"sample_time = -1: expected a finite number"):
        load_log(p, meta={**META, "sample_time": -1}, maps=MAPS, current_ok=True)


def test_keep_on_a_text_label_counts_what_it_leaves_out(tmp_path: Path) -> None:
    sel = RowSelection.from_options(keep=["Machining_Process~^Layer"])
    log = _load(_export(tmp_path / "e.csv"), selection=sel)
    assert log.n == 5 and log.n_read == 12
    assert log.left_out == [{"rule": "--keep 'Machining_Process~^Layer'", "left_out": 7}]
    assert list(log.row_numbers) == [4, 5, 6, 7, 8]
    np.testing.assert_allclose(log["t"], np.arange(3, 8) * 0.1)  # times of the file rows


def test_drop_with_a_conjunction_splits_the_record(tmp_path: Path) -> None:
    sel = RowSelection.from_options(drop=["Xcur>=1 & Xcur<2", "Machining_Process==Prep"])
    log = _load(_export(tmp_path / "e.csv"), selection=sel)
    # Xcur = 0.5 i - 1: rows i = 4, 5 have 1 <= Xcur < 2; Prep is i = 0..2
    assert [d["left_out"] for d in log.left_out] == [2, 3]
    assert list(log.row_numbers) == [4, 7, 8, 9, 10, 11, 12]
    assert list(log.segments) == [0, 1]


def test_drop_repeats_leaves_out_stale_copies(tmp_path: Path) -> None:
    rows = [
        "1,0,0.5,0,a,Prep",
        "2,1,0.7,0,b,Prep",
        "2,1,0.7,0,c,Prep",
        "3,1,0.9,0,a,Prep",
        "3,1,0.8,0,a,Prep",
    ]  # row 3 repeats row 2 in X*, row 5 differs in Xcur
    sel = RowSelection.from_options(drop_repeats="X*")
    log = _load(_export(tmp_path / "e.csv", rows=rows), selection=sel)
    assert log.left_out == [{"rule": "--drop-repeats 'X*'", "left_out": 1}]
    assert list(log.row_numbers) == [1, 2, 4, 5]


def test_a_non_finite_value_in_a_row_left_out_is_no_refusal(tmp_path: Path) -> None:
    rows = ["1,0,0.5,0,a,Prep", "2,1,nan,0,b,Bad", "3,1,0.9,0,a,Prep"]
    p = _export(tmp_path / "e.csv", rows=rows)
    with pytest.raises(LogFormatError, match=r"column 'tau_m', row 2: expected a finite value"):
        _load(p)
    log = _load(p, selection=RowSelection.from_options(drop=["Machining_Process==Bad"]))
    assert log.n == 2


def test_phases_are_masks_over_the_rows_used(tmp_path: Path) -> None:
    sel = RowSelection.from_options(
        drop=["Machining_Process==Prep"],
        phases={"load_rows": "Machining_Process~Layer", "nominal_rows": "Spindle<1"},
    )
    log = _load(_export(tmp_path / "e.csv"), selection=sel)
    assert log.n == 9
    assert log.phases["load_rows"].tolist() == [True] * 5 + [False] * 4
    assert not log.phases["nominal_rows"].any()


@pytest.mark.parametrize(
    ("kw", "match"),
    [
        ({"keep": ["Nope==1"]}, r"e.csv: --keep 'Nope==1': column 'Nope' does not exist; found "),
        (
            {"keep": ["Machining_Process<3"]},
            r"--keep 'Machining_Process<3': column 'Machining_Process', row 1: expected numbers "
            r"for '<', found text 'Prep'",
        ),
        (
            {"drop": ["Xcur>high"]},
            r"--drop 'Xcur>high': column 'Xcur' holds numbers: expected a number after '>', "
            r"found 'high'",
        ),
        (
            {"keep": ["Xcur>100"]},
            r"the row selection leaves no row: expected at least one of "
            r"12 rows; left out 12 by --keep 'Xcur>100'",
        ),
        ({"drop_repeats": "Q*"}, r"--drop-repeats 'Q\*': expected column names or patterns"),
    ],
)
def test_selection_refusals_name_what_is_wrong(tmp_path: Path, kw: dict, match: str) -> None:
    p = _export(tmp_path / "e.csv")
    with pytest.raises(LogFormatError, match=match):
        _load(p, selection=RowSelection.from_options(**kw))


@pytest.mark.parametrize(
    ("text", "match"),
    [
        ("Xcur", r"term 'Xcur': expected COLUMN OP VALUE"),
        ("Xcur=3", r"term 'Xcur=3': expected COLUMN OP VALUE"),
        ("Xcur>1 & ", r"term '': expected COLUMN OP VALUE"),
        ("Label~(", r"'\(': expected a regular expression"),
    ],
)
def test_bad_conditions_are_refused(text: str, match: str) -> None:
    with pytest.raises(LogFormatError, match=match):
        parse_condition(text, "--drop")


def test_quoted_values_and_equality_on_text() -> None:
    c = parse_condition("Machining_Process=='Layer 1 Up' & Xcur != 2", "--keep")
    assert [(t.column, t.op, t.value) for t in c.terms] == [
        ("Machining_Process", "==", "Layer 1 Up"),
        ("Xcur", "!=", "2"),
    ]


def test_sidecar_file_beside_the_export(tmp_path: Path) -> None:
    p = _export(tmp_path / "e.csv")
    p.with_suffix(".json").write_text(json.dumps(META))
    log = load_log(p, maps=MAPS, current_ok=True)
    assert log.sample_time == pytest.approx(0.1)
