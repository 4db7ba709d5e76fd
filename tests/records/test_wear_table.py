"""Reading a wear table: Latin-1 bytes, the column map with dotted names, refusals."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from server.errors import LogFormatError
from server.records.wear_table import parse_tools, parse_wear_map, read_wear_table


def test_latin1_bytes_in_unused_columns_do_not_split_rows(tmp_path: Path) -> None:
    # 0xB5 (micro) and 0x85 (NEL in Latin-1, a line break to str.splitlines) in a cell
    p = tmp_path / "t.csv"
    text = "tool,Vb,TV2.Z_MEAN,note_\xb5\r\n3,0,80.5,a\x85b\r\n3,12.5,81,\r\n5,1,79,c\r\n"
    p.write_bytes(text.encode("latin-1"))
    t = read_wear_table(p, ["TV2.Z_MEAN"])
    assert t.tools == [3, 5] and t.has_vb
    assert np.array_equal(t.column("Vb", 3), [0.0, 12.5])
    assert np.array_equal(t.columns["TV2.Z_MEAN"], [80.5, 81.0, 79.0])


def test_map_with_dots_scale_and_offset(tmp_path: Path) -> None:
    m = parse_wear_map("TV2.Z_MEAN=drive.z.torque*0.5+2")
    assert (m.column, m.source, m.scale, m.offset) == ("TV2.Z_MEAN", "drive.z.torque", 0.5, 2.0)
    p = tmp_path / "t.csv"
    p.write_text("tool,drive.z.torque\n7,10\n7,20\n", encoding="latin-1")
    t = read_wear_table(p, ["TV2.Z_MEAN"], ["TV2.Z_MEAN=drive.z.torque*0.5+2"])
    assert np.array_equal(t.columns["TV2.Z_MEAN"], [7.0, 12.0]) and not t.has_vb


def test_refusals(tmp_path: Path) -> None:
    p = tmp_path / "t.csv"
    p.write_text("tool,Vb,F_f_MEAN\n3,0,300\n3,1,\n", encoding="latin-1")
    with pytest.raises(LogFormatError, match=r"t\.csv: column 'F_f_MEAN', row 3.*empty cell"):
        read_wear_table(p, ["F_f_MEAN"])
    p.write_text("tool,Vb,F_f_MEAN\n3.5,0,300\n", encoding="latin-1")
    with pytest.raises(LogFormatError, match=r"column 'tool', row 2: expected a tool number"):
        read_wear_table(p, ["F_f_MEAN"])
    with pytest.raises(LogFormatError, match="no such file"):
        read_wear_table(tmp_path / "none.csv", ["F_f_MEAN"])
    p.write_text("tool,Vb,F_f_MEAN\n3,0,300\n", encoding="latin-1")
    t = read_wear_table(p, ["F_f_MEAN"])
    with pytest.raises(LogFormatError, match=r"--train-tools: tool 4 expected .* found tools 3"):
        parse_tools("3,4", t, "--train-tools")
    assert parse_tools(None, t, "--test-tools") is None
