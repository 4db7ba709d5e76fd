"""The service's routers, one module per concern (included by ``create_app``)."""

from __future__ import annotations

from fastapi import APIRouter

from server.service.routes import control, params, replay, reports, status, stream

ROUTERS: tuple[APIRouter, ...] = (
    status.router,
    params.router,
    control.router,
    reports.router,
    replay.router,
    stream.router,
)
