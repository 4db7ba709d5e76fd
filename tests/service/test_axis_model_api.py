"""``/api/axis-model``: a rigid residual report's effects for the axes' live models, by
name from the reports area or as JSON; refused with the field named when it is not one."""

from __future__ import annotations

import json
from pathlib import Path

import httpx
from _live import serve

REPORT = {"kind": "rigid", "effects": [{"name": "coulomb_asymmetry",
                                        "params": {"abs_v": 0.0, "dir_pos": 0.0}}]}  # fmt: skip


def test_a_report_by_name_is_kept_for_the_axes_and_removed_again(tmp_path: Path) -> None:
    rep = tmp_path / "reports" / "emps-head" / "report.json"
    rep.parent.mkdir(parents=True)
    rep.write_text(json.dumps(REPORT))
    with serve(scenario="default", data_dir=tmp_path) as hp:
        base = f"http://{hp}/api/axis-model"
        assert httpx.get(base).json()["axes"] == {}
        r = httpx.post(base, json={"name": "emps-head"})
        # the simulator describes no machine: kept for the axes part of a feed's machine
        assert r.status_code == 200 and r.json()["axes"] == {"*": ["coulomb_asymmetry"]}
        both = httpx.post(base, json={"name": "emps-head", "report": REPORT})
        assert both.status_code == 422 and "exactly one of 'name' or 'report'" in both.text
        missing = httpx.post(base, json={"name": "nope"})
        assert missing.status_code in (404, 422)
        assert httpx.delete(base).json()["axes"] == {}
