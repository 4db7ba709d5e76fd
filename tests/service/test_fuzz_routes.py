"""Every route of the real app, fuzzed over real HTTP: no 5xx, every refusal in the one
error shape ``{"detail": [{field, allowed, got, msg}]}``.

The routes are read from the app itself (a route added later is fuzzed without editing
this file). Inputs: JSON with lone surrogates, nesting up to 1,200 levels, integers of
hundreds of digits, NaN and infinities, wrong types, raw bytes (non-UTF-8, UTF-16), odd
content types, path parameters and queries with any code point, and the three kinds of
caller (the operator's token, the viewer's, none).
"""

from __future__ import annotations

import json
import tempfile
from collections.abc import Iterator
from typing import Any
from urllib.parse import quote

import httpx
import pytest
from _live import OPERATOR, VIEWER, serve
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from server.service.app import create_app
from server.service.settings import Settings


def _routes() -> list[tuple[str, str]]:
    """(method, path template) of every HTTP route of the app (its OpenAPI document),
    plus its static files and the routes kept out of the document."""
    with tempfile.TemporaryDirectory() as d:
        app = create_app(Settings(scenario="default", viser=False, data_dir=d))
    out = [(m.upper(), p) for p, ms in app.openapi()["paths"].items() for m in ms]
    out += [("GET", "/"), ("GET", "/app.js"), ("GET", "/login"), ("GET", "/vendor/uplot/x.js"),
            ("GET", "/docs"), ("GET", "/openapi.json")]  # fmt: skip
    return out


ROUTES = _routes()
#: the routes drawn: those taking a body three times (most of the input checks are there)
DRAWN = [r for r in ROUTES for _ in range(3 if r[0] in ("POST", "PATCH") else 1)]
FIELDS = ["action", "value", "scenario", "name", "area", "path", "report", "observer_effects",
          "log", "holdout", "kind", "token", "spindle_rpm", "weight_on", "feed_scale"]  # fmt: skip
ODD = ["\ud800", "a\udfff", "\x00", "nl\n", "..", "../etc/passwd", "%2e%2e", "é", "\u202e"]

text = st.text(max_size=12) | st.sampled_from(ODD)
huge = st.integers(min_value=10**300, max_value=10**400) | st.integers(max_value=-(10**300))
scalars = (
    st.none() | st.booleans() | st.integers() | huge | st.floats() | text
    | st.sampled_from(["pause", "speed", "scenario", "start", "stop", "default", "rigid"])
)  # fmt: skip
values = st.recursive(
    scalars,
    lambda inner: st.lists(inner, max_size=3) | st.dictionaries(text, inner, max_size=3),
    max_leaves=8,
)
#: the values that broke the service before: a lone surrogate, a huge integer, deep nesting
nasty = (
    st.sampled_from(ODD) | huge | st.sampled_from([float("nan"), float("inf")])
    | st.integers(400, 600).map(lambda n: json.loads("[" * n + "]" * n))
)  # fmt: skip
bodies_json = (
    st.dictionaries(st.sampled_from(FIELDS), nasty, min_size=1, max_size=2)
    | st.dictionaries(st.sampled_from(FIELDS) | text, values, max_size=4)
    | values
)


def _deep(n: int, wrap: bool) -> bytes:
    core = b"[" * n + b"]" * n
    return b'{"action": ' + core + b"}" if wrap else core


raw_bodies = (
    bodies_json.map(lambda v: json.dumps(v, ensure_ascii=True).encode())  # \ud800 escapes
    | st.builds(_deep, st.integers(1, 1200), st.booleans())
    | st.binary(max_size=64)
    | bodies_json.map(lambda v: json.dumps(v).encode("utf-16", "surrogatepass"))
    | st.sampled_from([b"", b"\xff\xfe\x00", b"t,tau_m,q_m\n0,1,\xff\n", b"{", b"NaN"])
)
content_types = st.sampled_from(
    ["application/json", "text/plain", "application/octet-stream", "multipart/form-data",
     "application/json; charset=utf-16", "x/y", "x/\u00e9"]
)  # fmt: skip
callers = st.sampled_from(
    [f"Bearer {OPERATOR}"] * 12 + [f"Bearer {VIEWER}", "", "Bearer nope", "Basic x", "Bearer  x"]
)


def _fill(path: str, part: str) -> str:
    # path parameters as percent-encoded bytes of any code point (surrogates included)
    enc = quote(part.encode("utf-8", "surrogatepass"), safe="") or "x"
    out = path
    for key in ("{name}", "{job_id}"):
        out = out.replace(key, enc)
    return out


@st.composite
def requests(draw: st.DrawFn) -> dict[str, Any]:
    method, path = draw(st.sampled_from(DRAWN))
    method = draw(st.sampled_from([method] * 12 + ["PUT", "DELETE", "HEAD", "OPTIONS"]))
    url = _fill(path, draw(text))
    query = draw(st.dictionaries(st.sampled_from(["name", "x", "area"]), text, max_size=2))
    qs = "&".join(f"{k}={quote(v.encode('utf-8', 'surrogatepass'), safe='')}"
                  for k, v in query.items())  # fmt: skip
    headers: dict[str, Any] = {"content-type": draw(content_types).encode("utf-8")}
    auth = draw(callers)
    if auth:
        headers["authorization"] = auth
    body = draw(raw_bodies) if method not in ("GET", "HEAD") else b""
    return {"method": method, "url": url + (f"?{qs}" if qs else ""), "headers": headers,
            "content": body}  # fmt: skip


def assert_shaped(r: httpx.Response, method: str) -> None:
    """No 5xx; a 4xx has the one error body (a HEAD answer has no body to check)."""
    where = f"{method} {r.request.url} -> {r.status_code}: {r.text[:300]!r}"
    assert r.status_code < 500, where
    if r.status_code < 400 or method == "HEAD":
        return
    body = r.json()
    assert isinstance(body, dict) and set(body) == {"detail"}, where
    assert isinstance(body["detail"], list) and body["detail"], where
    for item in body["detail"]:
        assert set(item) == {"field", "allowed", "got", "msg"}, where
        assert all(isinstance(item[k], str) for k in ("field", "allowed", "msg")), where


@pytest.fixture(scope="module")
def client() -> Iterator[httpx.Client]:
    with (
        serve(scenario="default", token=OPERATOR, view_token=VIEWER, speed=5.0) as hp,
        httpx.Client(base_url=f"http://{hp}", timeout=60) as c,
    ):
        yield c


SEEN: dict[str, int] = {"requests": 0, "5xx": 0}


def test_every_api_route_is_in_the_fuzzed_list() -> None:
    paths = {p for _, p in ROUTES}
    for p in ("/api/control", "/api/params", "/api/uploads", "/api/analyses/{job_id}",
              "/api/records/{name}", "/residual/{name}/report.json", "/api/login"):  # fmt: skip
        assert p in paths


@settings(
    max_examples=300,
    deadline=None,
    suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow],
)
@given(req=requests())
def test_fuzz_every_route_no_5xx_and_one_error_shape(
    client: httpx.Client, req: dict[str, Any]
) -> None:
    r = client.request(**req)
    SEEN["requests"] += 1
    SEEN["5xx"] += r.status_code >= 500
    assert_shaped(r, req["method"])


def test_fuzz_counts() -> None:
    # runs after the fuzz (file order): the numbers of the run, printed with -s
    if not SEEN["requests"]:
        pytest.skip("the fuzz test did not run in this session")
    print(f"fuzz: {SEEN['requests']} requests over {len(ROUTES)} routes, {SEEN['5xx']} 5xx")
    assert SEEN["requests"] >= 100 and SEEN["5xx"] == 0
