"""The service's routers, one module per concern (included by ``create_app``).

:func:`routers` imports them when called: the fleet page and a worker import only
``session`` from here (through ``server.service.front``), not the service's routes and
the live loop behind them.
"""

from __future__ import annotations

from fastapi import APIRouter


def routers() -> tuple[APIRouter, ...]:
    """The service's routers, in the order they are included (the login routes are
    every process's: ``server.service.front.protect`` includes them)."""
    from server.service.routes import (
        analyses,
        control,
        events,
        params,
        records,
        replay,
        reports,
        status,
        stream,
        uploads,
        viser_proxy,
    )

    return (
        status.router,
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
