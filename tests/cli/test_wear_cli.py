"""`cutwatch wear` on the real turning-wear table (a few tools) and its refusals.

The table is ``../shared/data/turning-wear/segments.csv`` (Vicomtech, CC BY-SA 4.0); the
subsets written here are rows of it, byte for byte, in Latin-1.
"""

from __future__ import annotations

import csv
import json
from pathlib import Path

import numpy as np
import pytest
from _shared_data import TURNING_WEAR, shared_file

from server.cli.main import main

TABLE = shared_file(*TURNING_WEAR) or Path("segments.csv-not-found")
pytestmark = pytest.mark.skipif(not TABLE.exists(), reason="turning-wear data not present")


def subset(tmp_path: Path, tools: set[str], *, rename: dict[str, str] | None = None) -> Path:
    """Rows of ``tools`` (and the header, optionally renamed) of the real table."""
    lines = TABLE.read_bytes().decode("latin-1").splitlines(keepends=True)
    head = next(csv.reader([lines[0]]))
    ti = head.index("tool")
    if rename:
        head = [rename.get(h, h) for h in head]
    keep = [ln for ln in lines[1:] if next(csv.reader([ln]))[ti] in tools]
    out = tmp_path / "subset.csv"
    out.write_bytes((",".join(head) + "\r\n" + "".join(keep)).encode("latin-1"))
    return out


def test_leave_one_tool_out_on_three_tools(tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    t = subset(tmp_path, {"7", "11", "16"})
    out = tmp_path / "out"
    assert main(["wear", str(t), "--out", str(out), "--quiet"]) == 0
    assert "MAE" in capsys.readouterr().out
    with (out / "estimates.csv").open() as f:
        rows = list(csv.DictReader(f))
    assert list(rows[0]) == [
        "tool", "segment", "vb_true", "vb_est", "vb_lo", "vb_hi",
        "life_left", "life_left_lo", "life_left_hi",
    ]  # fmt: skip
    assert {r["tool"] for r in rows} == {"7", "11", "16"}
    assert len(rows) == 169 + 213 + 109
    lo, est, hi = (np.array([float(r[c]) for r in rows]) for c in ("vb_lo", "vb_est", "vb_hi"))
    assert np.all(lo <= est) and np.all(est <= hi)
    rep = json.loads((out / "report.json").read_text())
    ov = rep["overall"]
    assert set(ov["baselines"]) == {"linear", "gbr"}
    assert [m["tool"] for m in rep["per_tool"]] == [7, 11, 16]
    # the MAE in the report is the one of the CSV
    vb = np.array([float(r["vb_true"]) for r in rows])
    assert ov["mae"] == pytest.approx(float(np.mean(np.abs(est - vb))))
    assert 0.0 <= ov["coverage"] <= 1.0 and ov["interval_median_width"] > 0
    page = (out / "report.html").read_text()
    # verdict first, then the figures, then the folded tables
    assert page.index("class='verdict'") < page.index("<img") < page.index("<details>")
    assert page.count("<img") == 3
    assert "Each tool estimated by a model fitted on the others" in page


def test_train_test_model_written_then_read(tmp_path: Path) -> None:
    t = subset(tmp_path, {"7", "11", "16", "5"})
    model = tmp_path / "m.json"
    args = ["wear", str(t), "--quiet", "--no-baselines", "--signal", "drive_current"]
    assert main([*args, "--train-tools", "7,11,16", "--out", str(tmp_path / "a"),
                 "--model", str(model), "--criterion", "150"]) == 0  # fmt: skip
    m = json.loads(model.read_text())
    assert m["version"] == 1 and m["signal"] == "drive_current" and m["train_tools"] == [7, 11, 16]
    rep_a = json.loads((tmp_path / "a" / "report.json").read_text())
    assert rep_a["test_tools"] == [5] and rep_a["criterion_um"] == 150.0
    assert "Trained on tools 7, 11, 16" in (tmp_path / "a" / "report.html").read_text()
    # read back: the same estimates without refitting
    assert main([*args, "--model", str(model), "--out", str(tmp_path / "b"),
                 "--criterion", "150"]) == 0  # fmt: skip
    a = (tmp_path / "a" / "estimates.csv").read_text()
    b = (tmp_path / "b" / "estimates.csv").read_text()
    assert a == b


def test_map_reads_other_column_names(tmp_path: Path) -> None:
    t = subset(tmp_path, {"7", "16"}, rename={"F_f_MEAN": "feed.force.mean", "Vb": "VB_um"})
    out = tmp_path / "o"
    rc = main(["wear", str(t), "--out", str(out), "--quiet", "--no-baselines",
               "--map", "F_f_MEAN=feed.force.mean", "--map", "Vb=VB_um*1.0"])  # fmt: skip
    assert rc == 0
    assert json.loads((out / "report.json").read_text())["overall"]["mae"] > 0


@pytest.mark.parametrize(
    ("argv", "expect"),
    [
        (["--train-tools", "7,99"], ["--train-tools", "tool 99", "'tool'", "found tools 7, 16"]),
        (["--test-tools", "x"], ["--test-tools", "expected tool numbers"]),
        (["--map", "F_f_MEAN=nope"], ["column 'F_f_MEAN'", "mapped from 'nope'", "expected"]),
        (["--map", "F_f_MEAN=CV3.X_SK"], ["column 'CV3.X_SK'", "row", "empty cell"]),
        (["--map", "F_f_MEAN=="], ["--map", "expected COL=name"]),
        (["--criterion", "-3"], ["--criterion", "expected"]),
        (["--train-tools", "7", "--test-tools", "7"], ["share tool"]),
    ],
)
def test_refusals_name_what_is_wrong(
    tmp_path: Path, capsys: pytest.CaptureFixture, argv: list[str], expect: list[str]
) -> None:
    t = subset(tmp_path, {"7", "16", "11"} if "CV3.X_SK" in argv[-1] else {"7", "16"})
    rc = main(["wear", str(t), "--out", str(tmp_path / "o"), "--quiet", *argv])
    err = capsys.readouterr().err
    assert rc == 2, err
    for e in expect:
        assert e in err, err
    if "99" in argv[-1] or "=" in argv[-1]:  # file-level refusals name the file
        assert str(t) in err or "--map" in err, err


def test_missing_column_and_latin1(tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    # a Latin-1 header (µ is 0xB5) reads; the missing feed column is named with the file
    p = tmp_path / "t.csv"
    p.write_bytes("tool,Vb,F_f_MEAN,x_\xb5m\r\n1,0,300,a\x85b\r\n".encode("latin-1"))
    rc = main(["wear", str(p), "--out", str(tmp_path / "o"), "--quiet"])
    err = capsys.readouterr().err
    assert rc == 2
    assert str(p) in err and "'CON.G.FREAL'" in err and "expected in the header" in err, err
    assert "x_\xb5m" in err  # the header as found, decoded as Latin-1


def test_a_table_without_vb_is_estimated_with_a_model(
    tmp_path: Path, capsys: pytest.CaptureFixture
) -> None:
    train = subset(tmp_path, {"7", "11", "16"})
    model = tmp_path / "m.json"
    base = ["wear", "--quiet", "--no-baselines"]
    assert main([*base, str(train), "--train-tools", "7,11", "--test-tools", "16",
                 "--model", str(model), "--out", str(tmp_path / "a")]) == 0  # fmt: skip
    # the new tool's rows without the Vb column: estimates only, no vb_true, no scores
    lines = TABLE.read_bytes().decode("latin-1").splitlines()
    head = next(csv.reader([lines[0]]))
    keep = [i for i, h in enumerate(head) if h != "Vb"]
    rows = [next(csv.reader([ln])) for ln in lines[1:]]
    rows = [r for r in rows if r[head.index("tool")] == "5"]
    blind = tmp_path / "blind.csv"
    blind.write_text(
        "\n".join(",".join(r[i] for i in keep) for r in [head, *rows]) + "\n", encoding="latin-1"
    )
    assert main([*base, str(blind), "--model", str(model), "--out", str(tmp_path / "b")]) == 0
    with (tmp_path / "b" / "estimates.csv").open() as f:
        got = list(csv.DictReader(f))
    assert "vb_true" not in got[0] and len(got) == 88 and {r["tool"] for r in got} == {"5"}
    rep = json.loads((tmp_path / "b" / "report.json").read_text())
    assert "overall" not in rep and rep["per_tool"][0]["tool"] == 5
    # the same model for another signal is refused, naming the field and both values
    capsys.readouterr()
    rc = main([*base, str(blind), "--model", str(model), "--signal", "drive_torque",
               "--out", str(tmp_path / "c")])  # fmt: skip
    err = capsys.readouterr().err
    assert rc == 2 and "'signal'" in err and "'drive_torque'" in err and "'feed_force'" in err
    # without Vb and without a model there is nothing to fit on
    rc = main([*base, str(blind), "--out", str(tmp_path / "d")])
    err = capsys.readouterr().err
    assert rc == 2 and "column 'Vb'" in err and str(blind) in err


def test_hybrid_on_a_given_test_tool_and_its_refusals(
    tmp_path: Path, capsys: pytest.CaptureFixture
) -> None:
    """Issue 35's hybrid through the command: tool 16 estimated from 7, 10 and 11, the
    configuration chosen by leave-one-tool-out over those three."""
    t = subset(tmp_path, {"7", "10", "11", "16"})
    out = tmp_path / "hy"
    args = ["wear", str(t), "--method", "hybrid", "--test-tools", "16", "--first-list"]
    assert main([*args, "--out", str(out), "--quiet"]) == 0
    assert "hybrid" in capsys.readouterr().out
    with (out / "estimates.csv").open() as f:
        rows = list(csv.DictReader(f))
    assert len(rows) == 109 and {r["tool"] for r in rows} == {"16"}
    lo, est, hi = (np.array([float(r[c]) for r in rows]) for c in ("vb_lo", "vb_est", "vb_hi"))
    assert np.all(lo <= hi) and np.mean((est >= lo) & (est <= hi)) > 0.9
    rep = json.loads((out / "report.json").read_text())
    po = rep["given"]["pooled"]
    vb = np.array([float(r["vb_true"]) for r in rows])
    assert po["mae"] == pytest.approx(float(np.mean(np.abs(est - vb))), abs=1e-2)
    assert {"mae_linear", "mae_gbr5", "mae_prior"} <= set(po)
    for extra, what in ((["--train-tools", "7"], "--train-tools"), (["--set", "nope"], "--set")):
        rc = main([*args, *extra, "--out", str(out), "--quiet"])
        err = capsys.readouterr().err
        assert rc == 2 and what in err, err


def test_hybrid_leave_k_tools_out_quick(tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    """Repeated leave-k-tools-out through the command (``--quick``: the first draw of
    each k, the first list without boosting) on the spindle torque: every split's test
    tools are k distinct tools, the pooled MAE is the estimates', and each split says
    what its selection believed (inner score) beside what it made (optimism)."""
    out = tmp_path / "lk"
    args = ["wear", str(TABLE), "--method", "hybrid", "--set", "TV2.S", "--protocol", "leave-k"]
    assert main([*args, "--quick", "--out", str(out), "--quiet"]) == 0
    printed = capsys.readouterr().out
    rep = json.loads((out / "report.json").read_text())
    assert [p for p in ("l2o", "l3o", "l4o") if p in rep] == ["l2o", "l3o", "l4o"]
    assert "loto" not in rep
    with (out / "estimates.csv").open() as f:
        rows = list(csv.DictReader(f))
    for k in (2, 3, 4):
        v = rep[f"l{k}o"]
        assert v["splits"] == 1 and f"l{k}o, 1 splits" in printed
        mine = [r for r in rows if r["protocol"] == f"l{k}o"]
        split = {r["split"] for r in mine}
        assert len(split) == 1 and len(set(split.pop().split("+"))) == k
        assert {r["tool"] for r in mine} and len({r["tool"] for r in mine}) == k
        err = np.array([abs(float(r["vb_est"]) - float(r["vb_true"])) for r in mine])
        assert v["pooled"]["mae"] == pytest.approx(float(np.mean(err)), abs=1e-2)
        o = {key: v[key]["median"] for key in ("inner_score", "outer_score", "optimism")}
        assert o["optimism"] == pytest.approx(o["outer_score"] - o["inner_score"])
        assert 0 < o["inner_score"] < 300 and 0 < o["outer_score"] < 300
        assert 1 <= v["inner_close"]["median"] <= v["n_configs"] == 30
    rc = main([*args, "--test-tools", "3", "--out", str(out), "--quiet"])
    err = capsys.readouterr().err
    assert rc == 2 and "--protocol leave-k" in err and "--test-tools" in err
    rc = main([*args, "--k", "5", "--out", str(out), "--quiet"])
    err = capsys.readouterr().err
    assert rc == 2 and "--k" in err and "'5'" in err


def test_hybrid_diagnose_quick(tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    """``--diagnose`` (issue 35's misses taken apart after the results): tool 16 left
    out, quick list; the per-method table is printed, the JSON's pooled MAE is the
    estimates' own, the figure is a PNG; another protocol is refused naming it."""
    out = tmp_path / "dg"
    args = ["wear", str(TABLE), "--method", "hybrid", "--diagnose", "--test-tools", "16"]
    assert main([*args, "--quick", "--out", str(out), "--quiet"]) == 0
    printed = capsys.readouterr().out
    assert "monotone lower bound" in printed and "tool 16" in printed and "gbr_mean" in printed
    dg = json.loads((out / "diagnosis.json").read_text())
    (t,) = dg["tools"]
    assert t["tool"] == 16 and "quick" in dg["protocol"]
    vb = np.array(t["series"]["vb"])
    for m in ("ours", "linear", "gbr5", "gbr_mean"):
        e = np.array(t["series"][m])
        assert dg["pooled"][f"{m}_mae"] == pytest.approx(float(np.mean(np.abs(e - vb))))
    assert (out / "diagnosis.png").read_bytes()[:4] == b"\x89PNG"
    assert dg["spread"]["loto"]["ratio_mae"]["median"] == pytest.approx(
        dg["pooled"]["ours_mae"] / dg["pooled"]["linear_mae"]
    )
    rc = main([*args, "--protocol", "both", "--out", str(out), "--quiet"])
    err = capsys.readouterr().err
    assert rc == 2 and "--protocol both" in err and "--diagnose" in err
    for flag in ("--diagnose", "--quick"):  # without --method hybrid: refused, not ignored
        rc = main(["wear", str(TABLE), flag, "--out", str(out), "--quiet"])
        err = capsys.readouterr().err
        assert rc == 2 and flag in err and "--method hybrid" in err and "observer" in err, err


def test_hybrid_diagnose_leave_k_quick(tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    """``--diagnose --protocol leave-k --k 2 --quick``: one split of two tools; the ratio
    ours / linear measured every way, no per-tool diagnosis and no figure."""
    out = tmp_path / "dk"
    args = ["wear", str(TABLE), "--method", "hybrid", "--diagnose", "--protocol", "leave-k"]
    assert main([*args, "--k", "2", "--quick", "--out", str(out), "--quiet"]) == 0
    printed = capsys.readouterr().out
    assert "l2o (1 splits)" in printed and "pchip" in printed
    dg = json.loads((out / "diagnosis.json").read_text())
    assert list(dg["spread"]) == ["l2o"] and "tools" not in dg
    v = dg["spread"]["l2o"]
    assert v["ratio_mae"]["splits"] == 1 and v["ratio_mae_lb"]["median"] > 0
    assert not (out / "diagnosis.png").exists()
