"""FastAPI dependencies: the live loop, the settings, the data store, the operator role."""

from __future__ import annotations

from typing import Annotated

from fastapi import Depends, HTTPException, Request

from server.records.store import DataStore
from server.service.auth import operator
from server.service.http_errors import error
from server.service.loop import LiveLoop
from server.service.settings import Settings


def live_loop(request: Request) -> LiveLoop:
    """The app's :class:`LiveLoop` (started by the lifespan)."""
    loop: LiveLoop = request.app.state.loop
    return loop


def settings(request: Request) -> Settings:
    """The app's :class:`Settings`."""
    s: Settings = request.app.state.settings
    return s


def data_store(request: Request) -> DataStore:
    """The app's :class:`DataStore` (recordings, uploads, reports by name)."""
    st: DataStore = request.app.state.store
    return st


Live = Annotated[LiveLoop, Depends(live_loop)]
Config = Annotated[Settings, Depends(settings)]
Store = Annotated[DataStore, Depends(data_store)]


def conflict(field: str, allowed: str, got: object, msg: str) -> HTTPException:
    """A 409 (the request does not fit the service's state) in the one error shape."""
    return HTTPException(409, detail=[error(field, allowed, got, msg)])


#: route dependency of every state-changing endpoint: the operator role
#: (:func:`server.service.auth.operator`; the middleware has checked it already, the
#: dependency keeps it on the route and in the OpenAPI document)
Authorised = Depends(operator)
