"""A worker's HTTP side through the service's access model: the health is public (the
probes), the machine pages and their JSON need the service's tokens (a browser without a
session is sent to the login page), a machine the worker does not own is a 404 that
names it."""

from __future__ import annotations

import asyncio
from typing import Any

import httpx
from pydantic import SecretStr

from server.pipeline.broker import parse_broker_url
from server.pipeline.worker import Worker, WorkerConfig
from server.service.settings import Settings
from server.service.worker_app import create_worker_app

OPERATOR = "op-token-0123456789abcdef"
VIEWER = "view-token-0123456789abcdef"


def _get(app: Any, url: str, **kw: Any) -> httpx.Response:
    async def go() -> httpx.Response:
        t = httpx.ASGITransport(app=app)
        async with httpx.AsyncClient(transport=t, base_url="http://127.0.0.1") as c:
            return await c.get(url, **kw)

    return asyncio.run(go())


def test_the_worker_pages_use_the_services_tokens() -> None:
    w = Worker(parse_broker_url("mqtt://127.0.0.1:1"), WorkerConfig(machines=frozenset({"mill-1"})))
    w.adopt("mill-1")  # as when its meta arrives (the app's lifespan is not run here)
    app = create_worker_app(w, Settings(token=SecretStr(OPERATOR), view_token=SecretStr(VIEWER)))
    h = _get(app, "/api/health")
    assert h.status_code == 200 and h.json()["machines"] == 1  # public: the probes
    assert h.json()["status"] == "starting"  # not started: not ready
    assert _get(app, "/api/machines/mill-1").status_code == 401
    page = _get(app, "/m/mill-1/", headers={"accept": "text/html"})
    assert page.status_code == 303 and page.headers["location"] == "/login"
    for token in (VIEWER, OPERATOR):
        auth = {"Authorization": f"Bearer {token}"}
        r = _get(app, "/api/machines/mill-1", headers=auth)
        assert r.status_code == 200 and r.json()["machine"] == "mill-1"
        p = _get(app, "/m/mill-1/", headers=auth)
        assert p.status_code == 200 and "machine.js" in p.text
    missing = _get(app, "/api/machines/lathe-2", headers={"Authorization": f"Bearer {VIEWER}"})
    assert missing.status_code == 404
    assert missing.json()["detail"][0]["field"] == "machine"
    assert missing.json()["detail"][0]["got"] == "lathe-2"
    assert _get(app, "/api/machines/mill-1", headers={"Host": "evil.example"}).status_code == 400
