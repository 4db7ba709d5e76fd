"""The OPC UA node map: both spellings, errors naming the key, engineering units."""

from __future__ import annotations

import json
import math

import pytest

from server.errors import CutwatchError
from server.records.opcua_map import (
    eu_factor,
    load_node_map,
    node_map_from_dict,
    unece_id,
)

SHORT = {
    "sample_time": 0.1,
    "axes": {
        "X": {
            "kind": "rigid",
            "q_m": "ns=2;s=X.pos",
            "i_m": "ns=2;s=X.cur",
            "units": {"position": "m", "effort": "A"},
        },
        "Y": {"kind": "rigid", "q_m": "ns=2;s=Y.pos", "tau_m": "ns=2;i=77"},
    },
    "spindle": {"speed": "ns=2;s=S.speed", "power": "ns=2;s=S.power", "units": {"power": "kW"}},
    "identities": {"tool": "ns=2;s=tool"},
}


def test_the_short_spelling_is_a_machine_description() -> None:
    m = node_map_from_dict(SHORT)
    d = m.description
    assert d.sample_time == 0.1
    assert d.axis("X").signals == {"q_m": "ns=2;s=X.pos", "i_m": "ns=2;s=X.cur"}
    assert d.axis("Y").signals["tau_m"] == "ns=2;i=77"
    assert d.spindle is not None and d.spindle.unit("power") == "kW"
    assert d.identities == {"tool": "ns=2;s=tool"}
    # X states its position unit (it overrides the server's), Y takes the server's
    assert "X.q_m" in m.stated_units and "Y.q_m" not in m.stated_units
    assert m.open_position == {"Y"}
    assert "spindle.power" in m.stated_units and "spindle.speed" not in m.stated_units


def test_the_nested_spelling_is_read_as_it_is() -> None:
    d = {
        "sample_time": 0.01,
        "axes": {"Z": {"kind": "two_inertia", "units": {"position": "m"},
                       "signals": {"q_m": "ns=3;s=a", "q_l": "ns=3;s=b", "i_m": "ns=3;s=c"}}},
    }  # fmt: skip
    m = node_map_from_dict(d)
    assert m.description.axis("Z").kind == "two_inertia"


@pytest.mark.parametrize(
    ("change", "key", "expected"),
    [
        (lambda d: d["axes"]["X"].pop("q_m"), "axes.X.q_m", "a required key"),
        (lambda d: d.update(sample_time=1.0), "sample_time", "a value <= 0.1"),
        (lambda d: d["axes"]["X"].update(kind="flexible"), "axes.X.kind", "one of"),
        (lambda d: d["axes"]["X"].update(q_m="not a node"), "axes.X.q_m", "an OPC UA node id"),
        (lambda d: d["spindle"].update(speed="ns=2;s=X.pos"), "spindle.speed", "a source no other"),
        (lambda d: d["axes"]["Y"].pop("tau_m"), "axes.Y", "an effort"),
    ],
)
def test_a_bad_map_names_the_key_as_written(change, key, expected) -> None:  # type: ignore[no-untyped-def]
    d = json.loads(json.dumps(SHORT))
    change(d)
    with pytest.raises(CutwatchError) as e:
        node_map_from_dict(d, "node map m.json")
    msg = str(e.value)
    assert msg.startswith("node map m.json: key ")
    assert repr(key) in msg or f"'{key}." in msg, msg
    assert expected in msg, msg


def test_a_file_that_is_not_json_says_where(tmp_path) -> None:  # type: ignore[no-untyped-def]
    p = tmp_path / "m.json"
    p.write_text('{"sample_time": 0.1,\n "axes": }')
    with pytest.raises(CutwatchError, match=r"not JSON \(line 2"):
        load_node_map(p)
    with pytest.raises(CutwatchError, match="cannot read"):
        load_node_map(tmp_path / "missing.json")


def test_engineering_units_convert_to_the_description() -> None:
    assert unece_id("MMT") == 5066068  # OPC UA Part 8's example: millimetre
    assert eu_factor(unece_id("MMT"), "mm", "m") == pytest.approx(1e-3)
    assert eu_factor(None, "deg", "rad") == pytest.approx(math.pi / 180)
    assert eu_factor(unece_id("RPM"), None, "rpm") == pytest.approx(1.0)
    assert eu_factor(None, "1/min", "rpm") == pytest.approx(1.0)
    assert eu_factor(unece_id("KWT"), "kW", "W") == pytest.approx(1e3)
    assert eu_factor(None, "mm/min", "m/s") == pytest.approx(1e-3 / 60)
    assert eu_factor(None, "rad/s", "rpm", spindle=True) == pytest.approx(60 / (2 * math.pi))
    assert eu_factor(None, "furlong", "m") is None
    with pytest.raises(CutwatchError, match="is a length: expected a current"):
        eu_factor(None, "mm", "A")
