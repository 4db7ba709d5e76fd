"""The HTTP side of ``cutwatch worker``: probes, and a small page per machine it owns.

Why the worker serves its machines' pages itself (and not a gateway): the state a page
shows (the pipeline's latest values, the checkpoint, the feed's counters) lives in the
worker's memory, and the fleet row already carries each machine's link
(``<public url>/m/<machine>/``, in its estimates message): a click goes straight to the
process that owns the machine, with no second service to deploy and scale, and no
routing table to keep in step with the shards. One uvicorn per worker (not per machine),
no viser; the page polls one JSON route twice a second.

Routes:

``GET /api/health``            public (the probes): the worker's status, broker, machines;
                               503 when its loop has stopped on an error
``GET /api/machines``          the machines this worker owns
``GET /api/machines/{name}``   one machine: latest estimates, monitor status, feed
                               counters, checkpoint (404 naming it when not owned here)
``GET /m/{name}/``             the machine's page (``web/machine.html``)
``GET /metrics``               Prometheus counters

What is in front of the routes is every process's (:func:`server.service.front.protect`):
the same tokens (``CUTWATCH_TOKEN`` / ``CUTWATCH_VIEW_TOKEN``), the login page and its
session cookie, the Host allow-list and Origin checks, the headers, the 4xx shape; every
route but the health needs a viewer. No answer carries a server path: a checkpoint is
named by its file inside the data directory (:func:`public_checkpoint`).
"""

from __future__ import annotations

import asyncio
import contextlib
from collections.abc import AsyncIterator
from pathlib import Path
from typing import Any

from fastapi import FastAPI, HTTPException
from fastapi.responses import FileResponse, JSONResponse, PlainTextResponse

from server.pipeline.worker import Worker
from server.service import web_files
from server.service.front import protect
from server.service.http_errors import error
from server.service.settings import Settings

#: what a machine's answer says of its checkpoint (its file by its name in the data
#: directory: no answer carries a server path)
CHECKPOINT_KEYS = ("resumed", "resumed_t", "saved_t", "saved_wall", "refused", "error")


def create_worker_app(worker: Worker, settings: Settings) -> FastAPI:
    """The worker's app; the worker starts and stops with it (stop: checkpoints)."""

    @contextlib.asynccontextmanager
    async def lifespan(_app: FastAPI) -> AsyncIterator[None]:
        worker.adopt_saved()
        worker.start()
        try:
            yield
        finally:
            await asyncio.to_thread(worker.stop)

    app = FastAPI(title="cutwatch worker", lifespan=lifespan)
    protect(app, settings)  # the service's tokens, login, Host/Origin, headers, 4xx shape
    data_dir = worker.cfg.data_dir

    @app.get("/api/health", summary="the worker's status (public: probes)")
    def health() -> JSONResponse:
        h = worker.health()
        return JSONResponse(h, status_code=503 if h["status"] == "error" else 200)

    @app.get("/api/machines", summary="the machines this worker owns")
    def machines() -> list[dict[str, Any]]:
        out = []
        for name in sorted(worker.runs):
            m = worker.machine(name)
            if m is not None:
                m = {**m, "checkpoint": public_checkpoint(m["checkpoint"], data_dir)}
                out.append({k: m[k] for k in ("machine", "t", "blocks", "events", "checkpoint")})
        return out

    def owned(name: str) -> dict[str, Any]:
        m = worker.machine(name)
        if m is None:
            raise HTTPException(
                404,
                detail=[error("machine", f"one of this worker's {len(worker.runs)} machines",
                              name, f"machine {name!r} is not owned by {worker.name}")],
            )  # fmt: skip
        return m

    @app.get("/api/machines/{name}", summary="one machine's latest estimates and state")
    def machine(name: str) -> dict[str, Any]:
        m = owned(name)
        return {**m, "checkpoint": public_checkpoint(m["checkpoint"], data_dir)}

    @app.get("/m/{name}/", include_in_schema=False)
    def page(name: str) -> FileResponse:
        owned(name)
        return FileResponse(web_files.WEB_DIR / web_files.MACHINE_PAGE, media_type="text/html")

    @app.get("/metrics", response_class=PlainTextResponse, summary="Prometheus metrics")
    def metrics() -> str:
        h = worker.health()
        lines = [
            f"cutwatch_worker_machines {h['machines']}",
            f"cutwatch_worker_receiving_machines {h['receiving']}",
            f"cutwatch_worker_resumed_machines {h['resumed']}",
            f"cutwatch_worker_dropped_samples_total {h['dropped_samples']}",
            f"cutwatch_worker_broker_connected {int(h['connected'])}",
            f"cutwatch_worker_loop_seconds_p50 {h['loop_ms_p50'] / 1e3:.6f}",
        ]
        return "\n".join(lines) + "\n"

    app.mount("/", web_files.page_files(web_files.MACHINE), name="web")
    return app


def public_checkpoint(cp: dict[str, Any], data_dir: Path | None) -> dict[str, Any]:
    """A machine's checkpoint as its answers give it: the file by its name inside the
    data directory (``state/<machine>.npz``), and the data directory's path taken out of
    the messages (a refused file's error names it)."""
    out: dict[str, Any] = {k: cp[k] for k in CHECKPOINT_KEYS if k in cp}
    path = cp.get("path")
    out["file"] = None
    if path and data_dir is not None:
        file = Path(path)
        for d in (data_dir, data_dir.resolve()):
            if file.is_relative_to(d):
                out["file"] = file.relative_to(d).as_posix()
                break
    dirs = (data_dir, data_dir.resolve()) if data_dir is not None else ()
    roots = sorted({f"{d}/" for d in dirs if d.is_absolute()}, key=len, reverse=True)
    for key in ("refused", "error"):
        if isinstance(out.get(key), str):
            for root in roots:
                out[key] = out[key].replace(root, "DATA_DIR/")
    return out
