"""What every cutwatch HTTP process puts in front of its routes, built once.

Three processes answer browsers and scripts: the service (``cutwatch serve``,
``server.service.app``), the fleet page (``cutwatch fleet``, ``server.service.fleet``) and
a plant's worker (``cutwatch worker``, ``server.service.worker_app``). Each builds its
FastAPI app with its own routes and hands it to :func:`protect`, and each command runs it
with :func:`uvicorn_options`. So all three have, from one definition:

- the access model (``server.service.auth``): the ``viewer`` and ``operator`` tokens
  (``CUTWATCH_VIEW_TOKEN``, ``CUTWATCH_TOKEN``), the login page and its session cookie
  (``server.service.routes.session``), the Host allow-list (``CUTWATCH_ALLOWED_HOSTS``);
- the middleware (``server.service.middleware``), outermost first: ``Guard`` (a repeated
  Host refused, the Host allow-list, the Origin check by scheme, host and port, the role,
  the security headers with ``frame-ancestors 'none'``, the audit line, a WebSocket
  client's leaving logged at debug), ``BodyLimit`` (413), ``Utf8Bodies`` (415 for a body
  in another charset than UTF-8);
- the one error body of every 4xx (``server.service.error_handlers``);
- the HTTP layer's limits (``server.service.http_guard``: header and body timeouts, header
  size, connections per address) and the WebSocket implementation (a refused upgrade is
  an answer, not an ERROR line) and message limit.

The files each serves are its pages' own, listed (``server.service.web_files``).
"""

from __future__ import annotations

import asyncio
import logging
from collections.abc import Mapping
from typing import Literal, TypedDict

from fastapi import FastAPI

from server.service import error_handlers
from server.service.auth import Access
from server.service.middleware import BodyLimit, Guard, Utf8Bodies
from server.service.routes import session
from server.service.settings import Settings

#: largest WebSocket message accepted from a client (clients need send nothing)
WS_MAX_SIZE = 65536


def protect(
    app: FastAPI, settings: Settings, *, body_limits: Mapping[str, int] | None = None,
    raw_bodies: frozenset[str] = frozenset(),
) -> FastAPI:  # fmt: skip
    """Give ``app`` the access model, the login routes, the error handlers and the
    middleware of every process (see the module's docstring); ``app`` is returned.

    Call it before mounting a catch-all (``/``) of files, so that the login routes come
    first. ``body_limits``: paths with their own body limit (uploads); ``raw_bodies``:
    paths whose bodies are files kept as bytes, whatever their charset.
    """
    log_to_stderr()
    app.state.settings = settings
    app.state.access = Access.from_settings(settings)
    error_handlers.install(app)
    app.include_router(session.router)
    app.add_middleware(Utf8Bodies, raw=raw_bodies)
    app.add_middleware(BodyLimit, limit=settings.max_body_bytes, paths=dict(body_limits or {}))
    app.add_middleware(Guard)  # outermost: Host, Origin, role, headers, audit
    return app


class UvicornOptions(TypedDict):
    """The uvicorn options every process passes (``uvicorn.run``/``uvicorn.Config``)."""

    workers: int
    http: type[asyncio.Protocol]  # the guarded httptools protocol (limits, timeouts)
    ws: type[asyncio.Protocol]  # websockets-sansio, a refused upgrade not an error
    ws_max_size: int  # [bytes]
    ws_per_message_deflate: bool
    lifespan: Literal["on"]


def uvicorn_options(settings: Settings) -> UvicornOptions:
    """The uvicorn options of every process (one worker; shared by the tests' servers)."""
    from server.service.http_guard import WebSocketProtocol, guarded_protocol

    return {
        "workers": 1,
        # uvicorn's httptools protocol with header/body timeouts and a header-size limit
        "http": guarded_protocol(
            header_timeout=settings.header_timeout_s,
            body_timeout=settings.body_timeout_s,
            body_min_rate=settings.body_min_rate,
            max_header_bytes=settings.max_header_bytes,
            max_per_client=settings.max_connections_per_client,
        ),
        # uvicorn's websockets-sansio, a refused upgrade not logged as an error
        "ws": WebSocketProtocol,
        "ws_max_size": WS_MAX_SIZE,
        # each client would deflate the same frame again: off unless asked for
        "ws_per_message_deflate": settings.ws_deflate,
        "lifespan": "on",
    }


def log_to_stderr() -> None:
    """The process's own log lines (``cutwatch.*``: the audit trail, start-up notes) on
    stderr at INFO, beside uvicorn's (which configures only its own loggers)."""
    root = logging.getLogger("cutwatch")
    if not root.handlers:
        h = logging.StreamHandler()
        h.setFormatter(logging.Formatter("%(asctime)s %(name)s %(levelname)s: %(message)s"))
        root.addHandler(h)
        root.setLevel(logging.INFO)
