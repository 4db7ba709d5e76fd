"""The stream schema is one thing on both sides: the message models, web/schema.js from them.

``server/service/messages.py`` defines the messages; ``protocol.SCHEMA`` and the
dashboard's ``web/schema.js`` (``make schema``) are derived from the models. The frames
the server sends are validated against the models, and run through ``web/protocol.js``'s
``checkMessage`` under node.
"""

from __future__ import annotations

import json
import shutil
import subprocess
from pathlib import Path

import pytest

from harness.accuracy import RollingAccuracy
from server.cli.commands import schema
from server.pipeline.part import Channel, Chart
from server.service import protocol
from server.service.hub import Hub
from server.service.loop import LiveLoop
from server.service.messages import Accuracy, Data, Hello, LoopHealth, fields
from server.service.settings import Settings

WEB = Path(__file__).resolve().parents[2] / "web"
NODE = shutil.which("node")
needs_node = pytest.mark.skipif(NODE is None, reason="node is not installed")


def run_js(code: str, stdin: str = "") -> str:
    assert NODE is not None
    out = subprocess.run(
        [NODE, "--input-type=module", "-e", code],
        input=stdin,
        capture_output=True,
        text=True,
        timeout=30,
        cwd=WEB,
        check=False,
    )
    if out.returncode != 0:
        raise AssertionError(out.stderr)
    return out.stdout


def test_the_generated_schema_module_is_current() -> None:
    found = (WEB / "schema.js").read_text(encoding="utf-8")
    assert found == schema.text(js=True), (
        "web/schema.js is stale: a message model changed; regenerate it with `make schema` "
        "(cutwatch schema --js --out web/schema.js)"
    )


def test_schema_check_names_a_stale_file(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    from server.cli.main import main

    stale = tmp_path / "schema.js"
    stale.write_text(schema.text(js=True).replace('"stalls"', '"stall_count"'))
    assert main(["schema", "--js", "--check", str(stale)]) == 1
    assert f"{stale} is stale" in capsys.readouterr().err
    assert main(["schema", "--js", "--out", str(stale)]) == 0
    assert main(["schema", "--js", "--check", str(stale)]) == 0
    doc = json.loads(schema.text(js=False))
    assert doc["messages"]["health"]["x-version"] == LoopHealth.VERSION
    assert list(doc["messages"]["data"]["properties"]) == protocol.SCHEMA["data"]


def test_the_loop_builds_its_messages_from_the_models() -> None:
    loop = LiveLoop(Settings(scenario="default", viser=False), Hub(4))
    loop.pipeline.step(2 * loop.block_n)
    health = loop.health().model_dump()
    assert list(health) == fields(LoopHealth)
    assert LoopHealth.model_validate(health, strict=True).sim_t == loop.pipeline.t
    hello = Hello.model_validate_json(loop.hello())
    assert [c.name for c in hello.channels] == [c.name for c in loop.pipeline.channels()]
    acc = loop.pipeline.accuracy(digits=protocol.ACCURACY_DIGITS)
    assert list(acc) == fields(Accuracy)
    Accuracy.model_validate(acc, strict=True)


@needs_node
def test_schema_equal_on_both_sides() -> None:
    js = json.loads(
        run_js("import {SCHEMA} from './protocol.js';console.log(JSON.stringify(SCHEMA));")
    )
    assert js == protocol.SCHEMA


def accuracy(has_truth: bool) -> dict[str, object]:
    """A real rolling-accuracy summary (a NaN sample in it, the 10 s window not full)."""
    import numpy as np

    acc = RollingAccuracy(["f_fixed", "f_dfo"], 4e-4, "truth" if has_truth else "measured_force")
    f = np.sin(np.arange(125.0))
    est = {"f_fixed": f + 0.1, "f_dfo": f.copy()}
    est["f_dfo"][3] = float("nan")
    acc.update(est, f, 0.9 * f) if has_truth else acc.update(est, measured=f)
    return acc.summary(digits=protocol.ACCURACY_DIGITS)


#: a part's declarations: a chart with a fast truth channel and a slow one
CHART = Chart("toy", "a toy chart", fast=True)
CHANNELS = (
    *CHART.series(Channel("force_true", "N", "true", "force", truth=True)),
    Channel("J_L", "kg m^2", "J_L", "J_L"),
)


def frames(has_truth: bool = True) -> list[str]:
    hello = protocol.hello(
        CHANNELS,
        [CHART],
        [{"name": "toy", "running": True, "reason": ""}],
        4e-4,
        "default",
        {"spindle_rpm": 1500.0},
    )
    health = LoopHealth(
        sim_t=0.4,
        speed=1.0,
        paused=False,
        lag_ms=0.5,
        lag_p99_ms=2.0,
        realtime_factor=1.0,
        clients=1,
        dropped_total=0,
        stalls=0,
    ).model_dump()
    body = protocol.data_body(
        {
            "seq": 3,
            "wall": 1.0,
            "t": [0.1, 0.2],
            "ts": [0.1],
            "ch": {"force_true": protocol.samples([1.0, float("nan")]), "J_L": [2.8e-4]},
            "health": health,
            "knobs": {"spindle_rpm": 1500.0},
            "accuracy": accuracy(has_truth),
            "parts": [{"name": "toy", "running": False, "reason": "it is a toy"}],
        }
    )
    return [hello, protocol.with_dropped(body, 7)]


@needs_node
@pytest.mark.parametrize("has_truth", [True, False])
def test_js_accepts_what_python_sends(has_truth: bool) -> None:
    code = (
        "import {checkMessage} from './protocol.js';"
        "import {readFileSync} from 'node:fs';"
        "const lines = readFileSync(0, 'utf8').trim().split('\\n');"
        "console.log(JSON.stringify(lines.map((l) => checkMessage(l).type)));"
    )
    assert json.loads(run_js(code, "\n".join(frames(has_truth)))) == ["hello", "data"]


@pytest.mark.parametrize("has_truth", [True, False])
def test_python_frames_are_the_models(has_truth: bool) -> None:
    hello, data = frames(has_truth)
    Hello.model_validate_json(hello, strict=True)
    frame = Data.model_validate_json(data, strict=True)
    assert frame.dropped == 7 and frame.ch["force_true"] == [1.0, None]


def test_python_frames_follow_schema() -> None:
    hello, data = (json.loads(f) for f in frames())
    assert list(hello) == protocol.SCHEMA["hello"]
    assert list(data) == protocol.SCHEMA["data"]
    assert data["dropped"] == 7 and data["ch"]["force_true"] == [1.0, None]
    acc = data["accuracy"]
    assert list(acc) == protocol.SCHEMA["accuracy"]
    assert acc["mode"] == "truth" and acc["windows"] == [1.0, 10.0]
    assert acc["rms"]["f_fixed"] == [0.1, 0.1]  # 4 significant digits
    assert acc["span"] == [0.05, 0.05]  # what the windows really cover so far
    assert json.loads(frames(False)[1])["accuracy"]["floor"] == [None, None]


@pytest.mark.parametrize(
    ("bad", "message"),
    [
        ('{"type": "nope"}', "unknown message type nope"),
        ('{"type": "hello", "version": 1}', "hello message lacks channels"),
        (
            '{"type": "hello", "version": 99, "channels": [], "charts": [], "parts": [],'
            ' "sample_time": 1, "scenario": "", "knobs": {}}',
            "protocol version 99, this page speaks 2",
        ),
        (
            '{"type": "data", "dropped": 0, "seq": 1, "wall": 0, "t": [1, 2], "ts": [1],'
            ' "ch": {"x": [1, 2]}, "health": {}, "knobs": {}, "status": null,'
            ' "accuracy": {"mode": "truth", "against": "truth", "reason": "", "windows": [1, 10],'
            ' "span": [0, 0], "rms": {}, "rms_q": {}, "floor": [null, null]}}',
            "health lacks sim_t",
        ),
        (
            '{"type": "data", "dropped": 0, "seq": 1, "wall": 0, "t": [1, 2], "ts": [1],'
            ' "ch": {"x": [1, 2, 3]}, "health": {"sim_t": 0, "speed": 1, "paused": false,'
            ' "lag_ms": 0, "lag_p99_ms": 0, "realtime_factor": 1, "clients": 1,'
            ' "dropped_total": 0, "stalls": 0}, "knobs": {}, "status": null,'
            ' "accuracy": {"mode": "truth", "against": "truth", "reason": "", "windows": [1, 10],'
            ' "span": [0, 0], "rms": {}, "rms_q": {}, "floor": [null, null]}}',
            "channel x: 3 samples, t has 2, ts has 1",
        ),
        (
            '{"type": "data", "dropped": 0, "seq": 1, "wall": 0, "t": [], "ts": [],'
            ' "ch": {}, "health": {"sim_t": 0, "speed": 1, "paused": false,'
            ' "lag_ms": 0, "lag_p99_ms": 0, "realtime_factor": 1, "clients": 1,'
            ' "dropped_total": 0, "stalls": 0}, "knobs": {}, "status": null,'
            ' "accuracy": {"mode": "truth"}}',
            "accuracy lacks against, reason, windows, span, rms, rms_q, floor",
        ),
        (
            '{"type": "data", "dropped": 0, "seq": 1, "wall": 0, "t": [], "ts": [],'
            ' "ch": {}, "health": {"sim_t": 0, "speed": 1, "paused": false,'
            ' "lag_ms": 0, "lag_p99_ms": 0, "realtime_factor": 1, "clients": 1,'
            ' "dropped_total": 0, "stalls": 0}, "knobs": {}, "status": null,'
            ' "accuracy": {"mode": "x",'
            ' "windows": [], "span": [], "rms": {}, "rms_q": {}, "floor": [], "against": null,'
            ' "reason": ""}}',
            "accuracy mode x",
        ),
    ],
)
@needs_node
def test_js_rejects_malformed(bad: str, message: str) -> None:
    code = (
        "import {checkMessage} from './protocol.js';"
        "import {readFileSync} from 'node:fs';"
        "try { checkMessage(readFileSync(0, 'utf8')); console.log('accepted'); }"
        " catch (e) { console.log(e.message); }"
    )
    assert message in run_js(code, bad)


def test_samples_rounds_to_significant_digits_relative_to_the_largest() -> None:
    assert protocol.samples([5.7212345e-4, 1.0e-4], 3) == [5.72e-4, 1.0e-4]
    assert protocol.samples([123.456, 0.001], 4) == [123.5, 0.0]
    assert protocol.samples([float("inf"), 1.0], 3) == [None, 1.0]
    assert protocol.samples([float("nan")] * 2, 3) == [None, None]
    assert protocol.samples([], 3) == []


def test_interval_channels_are_streamed_by_the_live_pipeline() -> None:
    from server.pipeline.live_pipeline import LivePipeline

    chans = {c.name: c for c in LivePipeline("default").channels()}
    with_band = [c for c in chans.values() if c.interval is not None]
    assert {c.name for c in with_band} == {"J_L_seg", "B_L_seg", "F_CL_seg"}
    for c in with_band:
        assert c.interval is not None and c.chart == c.group  # on the parameter's chart
        for name in c.interval:
            assert name in chans and chans[name].grid == "ts", name


def hello_of_the_default_pipeline() -> str:
    from server.pipeline.live_pipeline import LivePipeline

    p = LivePipeline("default")
    return protocol.hello(
        p.channels(),
        p.charts(),
        p.parts(),
        p.sample_time,
        p.scenario,
        p.knob_values(),
    )


@needs_node
def test_charts_are_built_from_the_hello() -> None:
    # web/charts.js: every chart the parts declare, by page and order, each channel on its
    # chart in its order; an interval drawn as a band (greyed where not excited); a shaded
    # area between two channels; no channel name written in web/ for any of it
    code = (
        "import {chartSpecs, roles} from './charts.js';"
        "import {readFileSync} from 'node:fs';"
        "const hello = JSON.parse(readFileSync(0, 'utf8'));"
        "const specs = chartSpecs(hello);"
        "const n = new Set(hello.channels.map((c) => c.name)); n.delete('B_L_lo');"
        "const cut = chartSpecs({...hello, channels: hello.channels.filter((c) => n.has(c.name))});"
        "console.log(JSON.stringify({ids: specs.map((s) => [s.id, s.page]),"
        " J_L: specs.find((s) => s.id === 'J_L'), monitor: specs.find((s) => s.id === 'monitor'),"
        " B_L: cut.find((s) => s.id === 'B_L'), roles: roles(hello.channels)}));"
    )
    got = json.loads(run_js(code, hello_of_the_default_pipeline()))
    ids = [i for i, _ in got["ids"]]
    assert ids[:2] == ["monitor", "wear"] and {p for _, p in got["ids"][:2]} == {"operator"}
    assert ids[2] == "force" and {p for _, p in got["ids"][2:]} == {"research"}
    jl = got["J_L"]
    assert [s[0] for s in jl["series"]][:3] == ["J_L_true", "J_L_adaptive", "J_L_switching"]
    assert [[s[0], s[1], s[4]["mask"]] for s in jl["series"][3:]] == [
        ["J_L_seg", "identified, 95 % band", ["J_L_excited", 1]],
        ["J_L_seg", "not excited", ["J_L_excited", 0]],
        ["J_L_hi", "95 % upper", ["J_L_excited", 1]],
        ["J_L_lo", "95 % lower", ["J_L_excited", 1]],
    ]
    assert jl["bands"][0]["series"] == [6, 7] and jl["excited"] == "J_L_excited"
    # without one of its interval's channels, B_L's estimate is a plain series
    assert [s[0] for s in got["B_L"]["series"]][-1] == "B_L_seg" and got["B_L"]["bands"] == []
    mon = got["monitor"]
    names = [s[0] for s in mon["series"]]
    assert mon["bands"][0]["series"] == [1 + names.index("mon_upper"), 1 + names.index("mon_lower")]
    assert got["roles"] == {"reference": "f_true", "without_effects": "f_fixed",
                            "with_effects": "f_effects"}  # fmt: skip


def test_no_channel_name_is_written_in_web() -> None:
    # the dashboard builds its charts from the hello: a channel's name in web/ (but the
    # generated schema.js, which names none either) would be a chart that a part cannot
    # change by declaring it
    import re

    from server.pipeline.live_pipeline import LivePipeline

    names = {c.name for c in LivePipeline("default").channels()}
    found = {}
    for f in [*WEB.glob("*.js"), *WEB.glob("*.html")]:
        text = f.read_text(encoding="utf-8")
        hits = {n for n in names if re.search(rf"\b{re.escape(n)}\b", text)}
        if hits:
            found[f.name] = sorted(hits)
    assert found == {}


def test_schema_js_carries_a_type_for_every_message() -> None:
    js = (WEB / "schema.js").read_text(encoding="utf-8")
    for model in ("Hello", "Data", "HelloChannel", "HelloChart", "PartStatus", "EventMessage",
                  "Event", "LoopHealth", "Accuracy", "MonitorStatus", "Interval"):  # fmt: skip
        assert f"@typedef {{Object}} {model}\n" in js, model
    assert " * @property {Array<HelloChannel>} channels" in js
    assert ' * @property {("operator"|"research")} page' in js


@needs_node
@pytest.mark.parametrize("has_truth", [True, False])
def test_panels_accuracy_table(has_truth: bool) -> None:
    acc = json.loads(frames(has_truth)[1])["accuracy"]
    code = (
        "import {accuracyTable, accuracyTitle} from './panels.js';"
        "import {readFileSync} from 'node:fs';"
        "const acc = JSON.parse(readFileSync(0, 'utf8'));"
        "console.log(JSON.stringify({title: accuracyTitle(acc), ...accuracyTable(acc)}));"
    )
    got = json.loads(run_js(code, json.dumps(acc)))
    keys = [r["key"] for r in got["rows"]]
    if has_truth:
        assert "against the truth" in got["title"]
        assert keys == ["f_fixed", "f_dfo", "q_floor"] and len(got["head"]) == 5
        assert got["rows"][0]["cells"][0] == "0.100"
    else:
        assert "against the measured force" in got["title"] and "truth," not in got["title"]
        assert keys == ["f_fixed", "f_dfo"] and len(got["head"]) == 3
        assert got["head"][1].startswith("vs measured force")
    assert "(0.1 s so far)" in got["head"][1]  # 125 samples of 0.4 ms: 0.05 s


def hello_of(scenario: str) -> dict[str, object]:
    from server.pipeline.live_pipeline import LivePipeline

    p = LivePipeline(scenario)
    return json.loads(
        protocol.hello(
            p.channels(),
            p.charts(),
            p.parts(),
            p.sample_time,
            p.scenario,
            p.knob_values(),
        )
    )


@needs_node
def test_panels_parameter_rows_from_the_centres_hello() -> None:
    # web/panels.js (issue 31: the machine's page): the identified parameters are the
    # channels with an interval, in their order; a parameter never estimated (the stage's
    # J_L on the centre, whose part does not run) has no row; where the data do not
    # determine it, no number; the interval from its bounds' channels
    hello = hello_of("machining-centre")
    latest = {
        "X.M": 1356.2, "X.M_lo": 1352.0, "X.M_hi": 1360.4, "X.M_excited": 1.0,
        "Y.Fv": 3.25e-3, "Y.Fv_lo": 1.0e-3, "Y.Fv_hi": 5.5e-3, "Y.Fv_excited": 0.0,
        "Z.Fc": 401.4, "Z.Fc_lo": 390.2, "Z.Fc_hi": 412.6,  # no excited flag seen yet
    }  # fmt: skip
    code = (
        "import {parameterRows, parameterChannels} from './panels.js';"
        "import {readFileSync} from 'node:fs';"
        "const [hello, latest] = JSON.parse(readFileSync(0, 'utf8'));"
        "console.log(JSON.stringify({rows: parameterRows(hello.channels, latest),"
        " names: parameterChannels(hello.channels)}));"
    )
    got = json.loads(run_js(code, json.dumps([hello, latest])))
    assert [r["key"] for r in got["rows"]] == ["X.M", "Y.Fv", "Z.Fc"]
    x, y, z = got["rows"]
    assert x == {"key": "X.M", "label": "X mass (inertia)", "unit": "N s^2/m",
                 "value": "1356", "interval": "[1352, 1360]", "excited": True}  # fmt: skip
    assert y["value"] == "not excited" and y["interval"] == "–" and y["excited"] is False
    assert z["value"] == "401.4" and z["interval"] == "[390.2, 412.6]" and z["excited"] is None
    chans = {c["name"] for c in hello["channels"]}  # type: ignore[index]
    assert set(got["names"]) <= chans and {"J_L_seg", "X.M_lo", "Z.Fc_excited"} <= set(got["names"])
