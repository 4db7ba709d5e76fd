"""The machine description: its JSON Schema, the typed model, errors that name the key."""

from __future__ import annotations

import copy
import json
from typing import Any

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from common.errors import ParameterError
from common.machine_description import (
    AXIS_ROLES,
    IDENTITIES,
    KINDS,
    LEGACY_AXIS,
    SCHEMA,
    SCHEMA_PATH,
    SPINDLE_ROLES,
    DescriptionError,
    describe,
    from_dict,
    from_legacy,
)

#: a machining centre as its CNC exports it at 500 Hz: X with a linear scale, Y and Z
#: semi-closed loop, a spindle with speed and power, the program identities
CENTRE: dict[str, Any] = {
    "sample_time": 0.002,
    "axes": {
        "X": {
            "kind": "two_inertia",
            "signals": {"q_m": "X_q", "q_l": "X_scale", "q_cmd": "X_cmd", "i_m": "X_i"},
            "units": {"position": "m"},
            "K_t": 12.5,
        },
        "Y": {
            "kind": "rigid",
            "signals": {"q_m": "Y_q", "qd_m": "Y_v", "qdd_m": "Y_a", "tau_m": "Y_tau"},
            "units": {"position": "m", "effort": "N"},
            "nominal": {"M": 250.0},
        },
        "Z": {"kind": "rigid", "signals": {"q_m": "Z_q", "i_m": "Z_i"}, "units": {"position": "m"}},
    },
    "spindle": {"signals": {"speed": "S_rpm", "power": "S_kw"}, "units": {"power": "kW"}},
    "identities": {"program": "prog", "tool": "T", "line": "N", "override": "ovr"},
}


def test_the_schema_is_a_valid_draft_2020_12_schema_read_from_its_file() -> None:
    import jsonschema

    jsonschema.Draft202012Validator.check_schema(SCHEMA)
    assert json.loads(SCHEMA_PATH.read_text()) == SCHEMA
    # the model's vocabularies are the schema's, not a second copy
    assert KINDS == ("rigid", "two_inertia")
    assert {"q_m", "q_l", "q_cmd", "qd_m", "qd_cmd", "qdd_m", "qdd_cmd", "tau_m", "i_m"} <= set(
        AXIS_ROLES
    )
    assert set(SPINDLE_ROLES) >= {"speed", "current", "power", "torque", "load"}
    assert IDENTITIES == ("program", "tool", "line", "override")


def test_a_machining_centre_reads_into_the_typed_model() -> None:
    m = from_dict(CENTRE)
    assert m.axis_names == ("X", "Y", "Z") and m.rate_hz == pytest.approx(500.0)
    x, y, z = m.axes
    assert (x.kind, x.K_t, x.effort_unit, x.required_roles) == (
        "two_inertia",
        12.5,
        "N",
        ("q_m", "i_m", "q_l"),
    )
    assert (y.unit("qd_m"), y.unit("qdd_m"), y.unit("tau_m"), y.nominal) == (
        "m/s",
        "m/s^2",
        "N",
        {"M": 250.0},
    )
    assert z.K_t is None and z.unit("i_m") == "A"
    assert m.spindle is not None and (m.spindle.unit("speed"), m.spindle.unit("power")) == (
        "rpm",
        "kW",
    )
    src = m.sources()
    assert src["X_scale"].owner == "X" and src["X_scale"].role == "q_l"
    assert src["S_kw"].unit == "kW" and src["N"].owner == "identities"
    assert from_dict(m.to_dict()) == m  # the JSON form round-trips
    assert m.with_sample_time(0.001).rate_hz == pytest.approx(1000.0)


def _with(path: str, value: Any) -> dict[str, Any]:
    """CENTRE with the value at a dotted path set (``None``: the key removed)."""
    d = copy.deepcopy(CENTRE)
    *head, last = path.split(".")
    node = d
    for k in head:
        node = node[k]
    if value is None:
        del node[last]
    else:
        node[last] = value
    return d


@pytest.mark.parametrize(
    ("path", "value", "key", "expected", "found"),
    [
        ("sample_time", 1.0, "sample_time", "a value <= 0.1", "1.0"),
        ("sample_time", 5e-5, "sample_time", "a value >= 0.0001", "5e-05"),
        ("sample_time", "2ms", "sample_time", "a JSON number", "'2ms'"),
        ("sample_time", None, "sample_time", "a required key", "missing"),
        ("axes", {}, "axes", "at least 1 entries", "{}"),
        ("axes.Z.kind", "flexible", "axes.Z.kind", "one of ['rigid', 'two_inertia']", "'flexible'"),
        ("axes.Z.units.position", "mm", "axes.Z.units.position", "one of ['m', 'rad']", "'mm'"),
        ("axes.Y.units.effort", "kN", "axes.Y.units.effort", "one of ['N', 'N m']", "'kN'"),
        ("axes.X.signals.q_l", None, "axes.X.signals.q_l", "a load position q_l", "missing"),
        ("axes.Z.signals.i_m", None, "axes.Z.signals", "an effort: tau_m", "['q_m']"),
        ("axes.Z.signals.q_m", None, "axes.Z.signals.q_m", "a required key", "missing"),
        ("axes.Z.signals.qd", "Z_v", "axes.Z.signals.qd", "one of the keys", "unknown key 'qd'"),
        ("axes.Z.signals.i_m", "Y_q", "axes.Z.signals.i_m", "a source no other", "'Y_q'"),
        ("axes.Z.signals.i_m", "a,b", "axes.Z.signals.i_m", "text matching", "'a,b'"),
        ("axes.Z.signals.i_m", "", "axes.Z.signals.i_m", "at least 1 characters", "''"),
        ("axes.X.K_t", 0, "axes.X.K_t", "a value > 0", "0"),
        ("axes.Y.nominal.M", "heavy", "axes.Y.nominal.M", "a JSON number", "'heavy'"),
        ("axes.Y.nominal.M", float("nan"), "axes.Y.nominal.M", "a finite number", "nan"),
        ("axes.Y.nominal.M", True, "axes.Y.nominal.M", "a JSON number", "True"),
        ("axes.Y.colour", "red", "axes.Y.colour", "one of the keys", "unknown key 'colour'"),
        ("axes.2X", CENTRE["axes"]["Z"], "axes.2X", "an axis name", "'2X'"),
        ("spindle.signals.speed", None, "spindle.signals.speed", "a required key", "missing"),
        ("spindle.units.speed", "rps", "spindle.units.speed", "one of ['rpm'", "'rps'"),
        ("identities.part", "P", "identities.part", "one of the keys", "unknown key 'part'"),
    ],
)
def test_a_broken_description_is_refused_naming_the_key_the_expected_and_the_found(
    path: str, value: Any, key: str, expected: str, found: str
) -> None:
    with pytest.raises(DescriptionError) as err:
        from_dict(_with(path, value))
    e = err.value
    assert isinstance(e, ParameterError)  # the service maps it to a 422 naming the field
    assert e.name == key, str(e)
    assert expected in e.expected, str(e)
    assert f"key {key!r}: expected " in str(e) and str(e).endswith(f"found {found}"), str(e)


def test_a_misspelt_key_is_named_beside_the_missing_one() -> None:
    d = _with("axes.Z.signal", {"q_m": "Z_q", "i_m": "Z_i"})
    del d["axes"]["Z"]["signals"]
    with pytest.raises(DescriptionError, match="beside it the unknown key 'signal'"):
        from_dict(d)


def test_a_rate_at_a_bound_read_from_a_time_column_is_accepted() -> None:
    ts = 0.10000000000000142  # the median interval of a 10 Hz time column
    assert from_dict({**CENTRE, "sample_time": ts}).sample_time == ts
    with pytest.raises(DescriptionError, match="sample_time"):
        from_dict({**CENTRE, "sample_time": 0.1001})


def test_top_level_keys_of_the_carrier_are_left_alone() -> None:
    m = from_dict({**CENTRE, "schema": "cutwatch.meta", "recording": {"samples": 3}})
    assert m == from_dict(CENTRE)


@settings(max_examples=60, deadline=None)
@given(rate=st.floats(10.0, 10_000.0), kind=st.sampled_from(KINDS), rad=st.booleans())
def test_every_rate_from_10_hz_to_10_khz_and_both_kinds_round_trip(
    rate: float, kind: str, rad: bool
) -> None:
    sig = {"q_m": "q", "tau_m": "f"} | ({"q_l": "s"} if kind == "two_inertia" else {})
    d = {
        "sample_time": min(max(1.0 / rate, 1e-4), 0.1),
        "axes": {"A": {"kind": kind, "signals": sig, "units": {"position": "rad" if rad else "m"}}},
    }
    m = from_dict(d)
    assert from_dict(m.to_dict()) == m
    assert m.axes[0].effort_unit == ("N m" if rad else "N")


# -- the older carriers: a log sidecar or a meta of minor 0, one axis -----------------


def test_a_legacy_sidecar_is_one_axis() -> None:
    side = {"sample_time": 1e-3, "units": {"effort": "N", "position": "m"}, "kind": "rigid"}
    m = from_legacy(side, ["t", "q_m", "tau_m", "qd_m", "tool", "line"])
    (ax,) = m.axes
    assert ax.name == LEGACY_AXIS and ax.kind == "rigid"
    assert ax.signals == {"q_m": "q_m", "tau_m": "tau_m", "qd_m": "qd_m"}
    assert m.identities == {"tool": "tool", "line": "line"}
    assert describe(side, ["q_m", "tau_m", "qd_m", "tool", "line"]) == m


def test_a_legacy_current_with_its_torque_constant() -> None:
    side = {
        "sample_time": 4e-4,
        "units": {"effort": "A", "position": "rad"},
        "kind": "two_inertia",
        "nominal": {"K_t": 0.3, "J_L": 1e-3},
        "encoder_resolution": 1e-5,
    }
    m = from_legacy(side)  # what an older publisher may send: q_m, i_m, q_l, f_ext
    (ax,) = m.axes
    assert ax.signals == {"q_m": "q_m", "i_m": "i_m", "q_l": "q_l", "f_ext": "f_ext"}
    assert (ax.K_t, ax.effort_unit, ax.encoder_resolution) == (0.3, "N m", 1e-5)
    # an older log kept the current in its tau_m column
    assert from_legacy(side, ["q_m", "tau_m", "q_l"]).axes[0].signals["i_m"] == "tau_m"
    # without kind: a load position makes it two-inertia
    no_kind = {k: v for k, v in side.items() if k != "kind"}
    assert from_legacy(no_kind, ["q_m", "i_m", "q_l"]).axes[0].kind == "two_inertia"
    assert from_legacy(no_kind, ["q_m", "i_m"]).axes[0].kind == "rigid"


@pytest.mark.parametrize(
    ("side", "key"),
    [
        ({"sample_time": 1e-3}, "units"),
        ({"sample_time": 1e-3, "units": {"effort": "kN", "position": "m"}}, "units.effort"),
        ({"sample_time": 1e-3, "units": {"effort": "N", "position": "deg"}}, "units.position"),
        ({"sample_time": 1e-3, "units": {"effort": "N", "position": "m"}, "kind": "x"}, "kind"),
        ({"units": {"effort": "N", "position": "m"}}, "sample_time"),
    ],
)
def test_a_broken_legacy_carrier_names_its_own_key(side: dict[str, Any], key: str) -> None:
    with pytest.raises(DescriptionError) as err:
        from_legacy(side, ["q_m", "tau_m"])
    assert err.value.name == key
