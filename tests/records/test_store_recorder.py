"""Files by name only (no traversal, no absolute paths, no symlinks out) and recordings
that round-trip into the log reader."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pytest

from server.errors import CutwatchError
from server.records.data_areas import DataStore, NotFound
from server.records.measured_log import load_log
from server.records.recorder import Recorder

SIDE = {
    "sample_time": 4e-4,
    "units": {"effort": "N m", "position": "rad"},
    "kind": "two_inertia",
    "nominal": {"J_L": 1e-3},
}


@pytest.fixture
def store(tmp_path: Path) -> DataStore:
    s = DataStore(tmp_path / "data")
    (s.area("recordings") / "run1.csv").write_text("t\n0\n")
    (tmp_path / "secret.csv").write_text("x\n")
    os.symlink(tmp_path / "secret.csv", s.area("recordings") / "link.csv")
    return s


@pytest.mark.parametrize(
    "name",
    [
        "../secret.csv",
        "/etc/passwd",
        "..",
        ".hidden",
        "a/b",
        "link.csv",  # a symlink pointing out of the area
        "link",
        "missing",
        "",
        "run1.csv\x00",
    ],
)
def test_only_plain_names_inside_the_area_resolve(store: DataStore, name: str) -> None:
    with pytest.raises(NotFound, match="recordings: no item named") as err:
        store.resolve("recordings", name, suffixes=(".csv",))
    assert "secret" not in str(err.value) or name.startswith("..")


def test_a_plain_name_resolves_with_or_without_its_suffix(store: DataStore) -> None:
    a = store.resolve("recordings", "run1", suffixes=(".csv",))
    assert a == store.resolve("recordings", "run1.csv") and a.name == "run1.csv"


def test_the_answer_does_not_tell_whether_a_host_file_exists(store: DataStore) -> None:
    msgs = set()
    for name in ("/etc/passwd", "/etc/shadowx"):
        with pytest.raises(NotFound) as err:
            store.resolve("uploads", name)
        msgs.add(str(err.value).replace(name, "X"))
    assert len(msgs) == 1


def blocks(n_blocks: int, n: int = 125) -> list[dict[str, np.ndarray]]:
    out = []
    for b in range(n_blocks):
        k = np.arange(b * n, (b + 1) * n)
        out.append(
            {"t": k * 4e-4, "tau_m": np.sin(k * 1e-2), "q_m": k * 1e-3, "q_l": k * 1e-3 - 1e-6}
        )
    return out


def test_a_recording_round_trips_into_the_log_reader(tmp_path: Path) -> None:
    path = tmp_path / "rec.csv"
    r = Recorder(path, SIDE)
    for b in blocks(8):
        r.append(b)
    assert not path.exists()  # nothing under the final name before it is complete
    s = r.close()
    assert s["samples"] == 1000 and not s["active"] and s["end"] == "stopped"
    log = load_log(path)
    assert log.kind == "two_inertia" and log.nominal == {"J_L": 1e-3}
    ref = np.concatenate([b["q_m"] for b in blocks(8)])
    np.testing.assert_array_equal(log["q_m"], ref)
    assert [p.name for p in tmp_path.iterdir() if p.name.endswith(".tmp")] == []


@pytest.mark.parametrize(
    ("kw", "why"),
    [({"max_seconds": 0.1}, "duration limit"), ({"max_bytes": 5000}, "size limit")],
)
def test_a_recording_stops_itself_at_its_limit(tmp_path: Path, kw: dict, why: str) -> None:
    r = Recorder(tmp_path / "rec.csv", SIDE, **kw)
    for b in blocks(10):
        r.append(b)
    assert not r.active and why in r.limit_reason
    s = r.close()
    assert why in s["end"] and s["samples"] < 1250
    assert load_log(tmp_path / "rec.csv").n == s["samples"]


def test_an_empty_recording_leaves_nothing(tmp_path: Path) -> None:
    s = Recorder(tmp_path / "rec.csv", SIDE).close()
    assert s["samples"] == 0 and list(tmp_path.iterdir()) == []


def test_an_existing_name_is_refused(tmp_path: Path) -> None:
    (tmp_path / "rec.csv").write_text("t\n")
    with pytest.raises(CutwatchError, match="exists already"):
        Recorder(tmp_path / "rec.csv", SIDE)
