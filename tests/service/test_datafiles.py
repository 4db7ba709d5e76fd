"""Files by name only, through the real app: no path, no traversal, no symlink out, no
oversized upload, and no oracle over the host's file system (the same answer for an
existing and a missing host path); uploads checked by the log loader; an analysis job
on an upload, its progress, its report, and its effects installed by report name."""

from __future__ import annotations

import json
import os
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import httpx
import pytest
from _live import serve
from _wait import poll

from server.cli.main import main

LIMIT_MB = 4.0  # upload limit of the test server (the 10 s log: 2.8 MB)


def wait_for(pred: Callable[[], Any], timeout: float = 120.0) -> Any:
    return poll(pred, timeout, 0.1)


@pytest.fixture(scope="module")
def env(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    d = tmp_path_factory.mktemp("files")
    logs = d / "logs"
    logs.mkdir()
    log = logs / "ca.csv"  # 10 s with friction that differs by direction
    argv = ["simulate", "--out", str(log), "--seconds", "10", "--effect", "coulomb_asymmetry"]
    assert main(argv) == 0
    data = d / "data"
    (data / "recordings").mkdir(parents=True)
    (data / "reports").mkdir()
    outside = d / "outside"
    outside.mkdir()
    (outside / "x.csv").write_text(log.read_text())
    (outside / "x.json").write_text(log.with_suffix(".json").read_text())
    (outside / "rep").mkdir()
    (outside / "rep" / "report.json").write_text('{"observer_effects": []}')
    # links placed inside the areas that point out of them
    (data / "recordings" / "link.csv").symlink_to(outside / "x.csv")
    (data / "recordings" / "link.json").symlink_to(outside / "x.json")
    (data / "reports" / "linkrep").symlink_to(outside / "rep")
    (data / "reports" / "inner").mkdir()
    (data / "reports" / "inner" / "report.json").symlink_to(outside / "rep" / "report.json")
    return {"d": d, "log": log, "data": data, "outside": outside}


@pytest.fixture(scope="module")
def api(env: dict[str, Path]) -> Iterator[httpx.Client]:
    with (
        serve(scenario="default", data_dir=env["data"], upload_max_mb=LIMIT_MB) as hp,
        httpx.Client(base_url=f"http://{hp}", timeout=60) as c,
    ):
        yield c


def one_error(r: httpx.Response, status: int) -> dict[str, Any]:
    assert r.status_code == status, r.text
    (err,) = r.json()["detail"]
    assert set(err) == {"field", "allowed", "got", "msg"}
    return dict(err)


# ------------------------------------------------------------------ no path, no oracle
@pytest.mark.parametrize("route", ["/api/replay", "/api/observer-effects"])
def test_a_path_is_refused_the_same_whether_it_exists_or_not(api: httpx.Client, route: str) -> None:
    answers = []
    for path in ("/etc/passwd", "/etc/shadowx", "/nonexistent/dir/x.csv", "../../etc/hosts"):
        err = one_error(api.post(route, json={"path": path}), 422)
        assert err["field"] == "path" and err["got"] == path
        answers.append((err["allowed"], err["msg"]))
    assert len(set(answers)) == 1  # one answer: nothing learnt about the host
    assert answers[0][1].startswith("paths are not accepted")


@pytest.mark.parametrize(
    "name",
    ["/etc/passwd", "/etc/shadowx", "../../../etc/passwd", "..", "a/../../b", "link",
     "link.csv", ".hidden", "..%2fetc%2fpasswd", "ca/../../x", "nope"],
)  # fmt: skip
def test_replay_names_that_do_not_resolve_get_one_answer(api: httpx.Client, name: str) -> None:
    err = one_error(api.post("/api/replay", json={"name": name}), 422)
    assert err["field"] == "name" and err["got"] == name
    assert err["msg"] == (
        f"recordings or uploads: no item named {name!r} (expected the name of one of the "
        "service's recordings or uploads, as listed by the API; paths are not accepted)"
    )


@pytest.mark.parametrize("name", ["/etc", "../outside/rep", "linkrep", "inner", "nope", ".."])
def test_effects_reports_that_do_not_resolve_get_one_answer(api: httpx.Client, name: str) -> None:
    err = one_error(api.post("/api/observer-effects", json={"report": name}), 422)
    assert err["field"] == "report"
    assert err["msg"].startswith(f"reports: no item named {name!r} (expected the name")


@pytest.mark.parametrize("name", ["link.csv", "link", "%2e%2e%2foutside%2fx.csv", "..%2f..%2fx"])
def test_downloads_do_not_follow_links_out(api: httpx.Client, name: str) -> None:
    r = api.get(f"/api/records/{name}")
    assert r.status_code == 404 and r.headers["content-type"] == "application/json"
    assert "tau_m" not in r.text  # the file's header is not served


def test_analysis_of_a_name_that_does_not_resolve(api: httpx.Client) -> None:
    for name in ("/etc/passwd", "link.csv", "../logs/ca.csv"):
        err = one_error(api.post("/api/analyses", json={"log": name}), 422)
        assert err["field"] == "name" and "no item named" in err["msg"]


# ------------------------------------------------------------------ uploads
def test_oversized_upload_is_refused_while_streaming(
    api: httpx.Client, env: dict[str, Path]
) -> None:
    big = b"t,tau_m,q_m\n" + b"0.0,0.0,0.0\n" * 400_000  # 4.8 MB > 4 MB
    err = one_error(api.post("/api/uploads", params={"name": "big.csv"}, content=big), 413)
    assert err["msg"] == "request body larger than 4000000 bytes"

    def chunks() -> Iterator[bytes]:  # no Content-Length: counted as it streams
        for _ in range(100):
            yield b"0.0,0.0,0.0\n" * 5000

    r = api.post("/api/uploads", params={"name": "big2.csv"}, content=chunks())
    err = one_error(r, 413)
    assert err["field"] == "body" and err["got"] > 4_000_000
    # nothing kept, no temporary file (removed as the route sees the stream end)
    wait_for(lambda: not list((env["data"] / "uploads").iterdir()), 5.0)


@pytest.mark.parametrize("name", ["../x.csv", "/etc/x.csv", ".x.csv", "x.txt", "x", "a b.csv"])
def test_upload_names(api: httpx.Client, name: str) -> None:
    err = one_error(api.post("/api/uploads", params={"name": name}, content=b"1"), 422)
    assert err["field"] == "name" and err["got"] == name


def test_a_bad_log_is_refused_with_the_loaders_message_and_removed(
    api: httpx.Client, env: dict[str, Path]
) -> None:
    up = env["data"] / "uploads"
    r = api.post("/api/uploads", params={"name": "bad.csv"}, content=b"t,x\n0,1\n")
    err = one_error(r, 422)
    assert err["msg"] == (
        'bad.csv: units not declared: expected sidecar key \'units\' = {"effort": "N" | '
        '"N m" | "A", "position": "m" | "rad"} (in bad.json or --meta), found None '
        "(the upload 'bad.csv' was removed)"
    )
    assert not (up / "bad.csv").exists()
    side = env["log"].with_suffix(".json").read_bytes()
    assert api.post("/api/uploads", params={"name": "bad.json"}, content=side).is_success
    rows = env["log"].read_text().splitlines()
    rows[100] = rows[100].replace(",", ",nan,", 1).rsplit(",", 1)[0]  # a non-finite value
    r = api.post("/api/uploads", params={"name": "bad.csv"}, content="\n".join(rows).encode())
    err = one_error(r, 422)
    assert "row 100: expected a finite value, found nan" in err["msg"]
    assert str(env["d"]) not in err["msg"]
    assert not (up / "bad.csv").exists() and (up / "bad.json").exists()
    err = one_error(api.post("/api/uploads", params={"name": "x.json"}, content=b"[1]"), 422)
    assert "x.json: expected a JSON object, found list" in err["msg"]


# ------------------------------------------------------------------ the loop, by name
def test_upload_analyse_install(api: httpx.Client, env: dict[str, Path]) -> None:
    side = env["log"].with_suffix(".json").read_bytes()
    r = api.post("/api/uploads", params={"name": "ca.json"}, content=side)
    assert r.status_code == 200 and r.json()["kind"] == "sidecar"
    r = api.post("/api/uploads", params={"name": "ca.csv"}, content=env["log"].read_bytes())
    assert r.status_code == 200, r.text
    info = r.json()
    assert info["checked"] and info["samples"] == 25000 and info["log_kind"] == "two_inertia"
    err = one_error(api.post("/api/uploads", params={"name": "ca.csv"}, content=b"1"), 409)
    assert err["msg"] == "upload 'ca.csv' exists already"
    names = {u["name"] for u in api.get("/api/uploads").json()["uploads"]}
    assert {"ca.csv", "ca.json"} <= names

    r = api.post("/api/analyses", json={"log": "ca", "holdout": 0.3})
    assert r.status_code == 202, r.text
    job = r.json()
    assert job["state"] in ("queued", "running") and job["report"] == "ca"
    err = one_error(api.post("/api/analyses", json={"log": "ca"}), 409)
    assert err["msg"].startswith(f"an analysis is running already (job {job['id']}")
    seen: list[float] = []

    def done() -> dict[str, Any] | None:
        j = api.get(f"/api/analyses/{job['id']}").json()
        seen.append(j["progress"])
        return j if j["state"] in ("done", "failed") else None

    j = wait_for(done, 300)
    assert j["state"] == "done", j["message"]
    assert seen == sorted(seen) and j["progress"] == 1.0
    assert any(0.0 < p < 1.0 for p in seen)  # progress seen under way
    assert j["report_url"] == "/residual/ca/"
    assert "coulomb_asymmetry" in j["selected"] or "offset" in j["selected"], j["selected"]
    assert j["rms_after"] < 0.7 * j["rms_before"]  # measured: 0.0245 / 0.0467 = 0.52
    page = api.get(j["report_url"])
    assert page.status_code == 200 and "<html" in page.text.lower()
    # no server path in the report: its log by name (issue 20)
    assert api.get("/residual/ca/report.json").json()["log"] == "ca.csv"
    assert str(env["data"]) not in page.text
    assert not [p for p in (env["data"] / "reports").iterdir() if p.name.startswith(".")]

    r = api.post("/api/observer-effects", json={"report": "ca"})
    assert r.status_code == 200, r.text
    assert r.json()["observer_effects"], r.json()
    assert api.delete("/api/observer-effects").is_success

    # a second analysis of the same log gets a report of its own
    j2 = api.post("/api/analyses", json={"log": "ca", "area": "uploads"}).json()
    assert j2["report"] == "ca-2"
    j2 = wait_for(lambda: (v := api.get(f"/api/analyses/{j2['id']}").json())["finished"] and v)
    assert j2["state"] == "done"
    assert [x["id"] for x in api.get("/api/analyses").json()["jobs"]] == [job["id"], j2["id"]]


def test_a_failing_analysis_says_why(api: httpx.Client, env: dict[str, Path]) -> None:
    log = env["log"].read_text().splitlines()
    short = "\n".join(log[:400]).encode()  # 0.16 s: too short for the held-out split
    side = env["log"].with_suffix(".json").read_bytes()
    assert api.post("/api/uploads", params={"name": "short.json"}, content=side).is_success
    assert api.post("/api/uploads", params={"name": "short.csv"}, content=short).is_success
    job = api.post("/api/analyses", json={"log": "short.csv"}).json()
    j = wait_for(lambda: (v := api.get(f"/api/analyses/{job['id']}").json())["finished"] and v)
    assert j["state"] == "failed" and j["report_url"] is None
    assert j["message"].startswith("short.csv: ") and str(env["d"]) not in j["message"]
    assert not (env["data"] / "reports" / "short").exists()
    assert os.listdir(env["data"] / "reports").count("short") == 0
    err = one_error(api.get("/api/analyses/nope"), 404)
    assert err["field"] == "job_id"
    assert json.loads(api.get("/api/analyses").text)["jobs"][-1]["state"] == "failed"
