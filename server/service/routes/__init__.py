"""The service's routers, one module per concern (included by ``create_app``)."""

from __future__ import annotations

from fastapi import APIRouter

from server.service.routes import (
    analyses,
    control,
    events,
    params,
    records,
    replay,
    reports,
    session,
    status,
    stream,
    uploads,
    viser_proxy,
)

ROUTERS: tuple[APIRouter, ...] = (
    status.router,
    session.router,
    params.router,
    control.router,
    reports.router,
    replay.router,
    records.router,
    events.router,
    uploads.router,
    analyses.router,
    stream.router,
    viser_proxy.router,
)
