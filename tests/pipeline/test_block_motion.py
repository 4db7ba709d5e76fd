"""What the CNC says of a block (server/pipeline/block_motion.py): the live monitors'
``cutting=`` from the program's text, else from the axes' commanded feed."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from machine.centre.program import program_variant
from server.experiments.benchmarks._plant_centres import record
from server.pipeline.block_motion import (
    FROM_FEED,
    FROM_PROGRAM,
    NOT_SAID,
    CanCut,
    cutting_lines,
)
from server.records.measured_log import load_log


def _shares(cc: CanCut, cols: dict[str, np.ndarray], chunk: int) -> dict[int, float]:
    """Each line's share of samples judged able to cut, the log stepped as a part steps
    it (chunks, split at the changes of the CNC's line)."""
    line = cols["line"]
    yes: dict[int, int] = {}
    total: dict[int, int] = {}
    last = None
    for c0 in range(0, len(line), chunk):
        sub = {k: v[c0 : c0 + chunk] for k, v in cols.items()}
        ln = sub["line"]
        cuts = np.flatnonzero(ln[1:] != ln[:-1]) + 1
        for a, b in zip([0, *cuts], [*cuts, len(ln)], strict=True):
            li = int(ln[a])
            can = cc(sub, li, a, b, li != last)
            yes[li] = yes.get(li, 0) + (b - a) * can
            total[li] = total.get(li, 0) + b - a
            last = li
    return {li: yes[li] / total[li] for li in total}


@pytest.mark.parametrize("index", [0, 1, 2])
def test_the_commanded_feed_says_what_the_program_says(tmp_path: Path, index: int) -> None:
    # a broker's drive blocks carry the commanded positions, not the program's text: in
    # one part of each program variant, no sample of a block the program says cannot
    # cut (rapids, plunges, tool changes, spindle starts, dwells) is judged able to, and
    # the G1 feeds in the plane are (but a block's first samples, before its commanded
    # path has moved: not known yet, so not a cut)
    record(tmp_path / "c.csv", index=index, seconds=40.0, event_rate=0.0)
    log = load_log(tmp_path / "c.csv")
    cc = CanCut(log.machine)
    assert cc.source == FROM_FEED
    want = cutting_lines(program_variant(index))
    got = _shares(cc, {k: np.asarray(v) for k, v in log.columns.items()}, chunk=50)
    assert set(got) == set(want)  # one whole part of the program ran
    assert {li: s for li, s in got.items() if not want[li] and s > 0.0} == {}
    assert {li: s for li, s in got.items() if want[li] and s < 0.99} == {}
    assert True in want.values() and False in want.values()


def test_the_program_text_is_read_where_the_source_holds_it() -> None:
    from server.pipeline.live_pipeline import LivePipeline

    p = LivePipeline("machining-centre", seed=0)
    p.step(25)
    st = p.monitor_status()
    assert st["cutting_from"] == FROM_PROGRAM
    assert st["axes_cutting_from"] == FROM_PROGRAM
    spindle = p.part("spindle")
    want = cutting_lines(program_variant(0))
    assert spindle.can_cut.lines == want
    # and the program's verdict is what the part passes, whatever the samples say
    assert spindle.can_cut({}, 60, 0, 0, True) is True
    assert spindle.can_cut({}, 30, 0, 0, True) is False


def test_a_feed_without_commanded_positions_says_nothing() -> None:
    from common.machine_description import from_dict as description_from_dict

    d = description_from_dict(
        {
            "sample_time": 0.002,
            "axes": {
                "X": {
                    "kind": "rigid",
                    "signals": {"q_m": "xq", "i_m": "xi"},
                    "units": {"position": "m", "effort": "N"},
                    "K_t": 10.0,
                }
            },
            "identities": {"line": "line"},
        }
    )
    cc = CanCut(d)
    assert cc.source == NOT_SAID
    assert cc({"xq": np.zeros(5), "line": np.zeros(5)}, 10, 0, 5, True) is True


def test_a_plunge_a_dwell_and_a_stopped_spindle_cannot_cut() -> None:
    from common.machine_description import from_dict as description_from_dict

    d = description_from_dict(
        {
            "sample_time": 0.002,
            "axes": {
                a: {
                    "kind": "rigid",
                    "signals": {"q_m": f"{a}q", "q_cmd": f"{a}c", "i_m": f"{a}i"},
                    "units": {"position": "m", "effort": "N"},
                    "K_t": 10.0,
                }
                for a in "XYZ"
            },
            "spindle": {"signals": {"speed": "s", "speed_cmd": "sc", "power": "p"}},
            "identities": {"line": "line"},
        }
    )
    n = 20
    ramp, held = np.linspace(0.0, 0.01, n), np.full(n, 0.05)

    def cols(x: np.ndarray, z: np.ndarray, s: float = 3000.0) -> dict[str, np.ndarray]:
        return {"Xc": x, "Yc": held, "Zc": z, "sc": np.full(n, s), "line": np.zeros(n)}

    cc = CanCut(d)
    assert cc.source == FROM_FEED
    assert cc(cols(ramp, held), 1, 0, n, True) is True  # G1 in the plane
    assert cc(cols(held, held), 2, 0, n, True) is False  # a dwell: nothing moves
    assert cc(cols(held, ramp), 3, 0, n, True) is False  # a plunge: Z alone
    assert cc(cols(ramp, ramp), 4, 0, n, True) is False  # a ramp entry: Z moves too
    assert cc(cols(ramp, held, 0.0), 5, 0, n, True) is False  # the spindle stopped
    # a block stays what it showed: Z moved in its first chunk, a later chunk in the
    # plane does not make it a cut; the next block starts afresh
    assert cc(cols(held, ramp), 6, 0, n, True) is False
    assert cc(cols(ramp + 0.01, ramp[-1] + 0 * ramp), 6, 0, n, False) is False
    assert cc(cols(ramp, held), 7, 0, n, True) is True
