"""The FastAPI application: REST, WebSocket stream, dashboard files.

Built by :func:`create_app`; the lifespan starts one :class:`~server.service.loop.LiveLoop`
thread and stops it (and tells every WebSocket client) on shutdown. Serve it with one
uvicorn worker: the simulation lives in the process (``cutwatch serve``). The routes are
in ``server.service.routes``; what every process has in front of them (tokens, login,
Host/Origin checks, headers, the one 4xx body ``{"detail": [{field, allowed, got,
msg}]}``) is ``server.service.front``'s; the files served are the dashboard's own
(``server.service.web_files``).
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
from collections.abc import AsyncIterator

from fastapi import FastAPI

from server.pipeline import part_registry
from server.records.data_areas import DataStore
from server.service import web_files
from server.service.analysis import Analyses
from server.service.front import protect
from server.service.hub import Hub
from server.service.loop import LiveLoop, checkpoint_path, loop_parts
from server.service.routes import routers
from server.service.settings import Settings, check_security

log = logging.getLogger("cutwatch.service")


def create_app(settings: Settings | None = None) -> FastAPI:
    """Build the service.

    Parameters
    ----------
    settings
        Configuration; read from the environment (``CUTWATCH_*``) when omitted.

    Raises
    ------
    CutwatchError
        When bound to a non-loopback address without ``CUTWATCH_TOKEN``.
    """
    s = settings if settings is not None else Settings()
    check_security(s)

    @contextlib.asynccontextmanager
    async def lifespan(app: FastAPI) -> AsyncIterator[None]:
        stale = app.state.store.clean_stale()  # nothing runs yet: all of it is left over
        if stale:
            log.warning(
                "removed %d temporary file(s) left by an interrupted run: %s",
                len(stale), ", ".join(stale)[:2000],
            )  # fmt: skip
        from server.service import upload_check

        # the upload checker's server process, started now (its imports take seconds)
        warming = asyncio.create_task(asyncio.to_thread(upload_check.warm))
        hub = Hub(s.client_buffer)
        hub.bind(asyncio.get_running_loop())
        part_registry.use(s.parts)  # the user's own parts, before any pipeline is built
        parts = loop_parts(s)
        loop = LiveLoop(
            s,
            hub,
            pipeline=parts.pipeline,
            feed=parts.feed,
            estimates_out=parts.estimates_out,
            events_out=parts.events_out,
            checkpoint=checkpoint_path(s),
            history=parts.history,
        )
        app.state.hub, app.state.loop = hub, loop
        if s.viser:
            from server.service.viser_scene import VISER_HOST, StageScene

            # loopback only: browsers reach it through /viser/, behind the session
            loop.scene = StageScene(VISER_HOST, s.viser_port)
        loop.start()
        try:
            yield
        finally:
            warming.cancel()
            app.state.analyses.close()
            hub.close()
            await asyncio.to_thread(loop.stop)
            if loop.scene is not None:
                loop.scene.stop()
            if parts.history is not None:
                parts.history.close()

    app = FastAPI(
        title="cutwatch",
        version="0.1.0",
        lifespan=lifespan,
        description="Live cutting-force observers on a simulated machine tool. Every 4xx "
        'answers {"detail": [{"field", "allowed", "got", "msg"}]} (schema ErrorBody).',
    )
    app.state.store = DataStore(s.data_dir, reports=s.reports_dir)
    app.state.analyses = Analyses(app.state.store)
    # tokens, login, Host/Origin, headers, body limits and charsets, the 4xx shape
    uploads = "/api/uploads"
    protect(app, s, body_limits={uploads: s.upload_max_bytes}, raw_bodies=frozenset({uploads}))
    for router in routers():
        app.include_router(router)
    uplot = web_files.uplot_files()
    if uplot is not None:
        app.mount("/vendor/uplot", uplot, name="uplot")
    app.mount("/", web_files.page_files(web_files.DASHBOARD, index="index.html"), name="web")
    return app
