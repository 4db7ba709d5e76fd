"""FastAPI dependencies: the live loop, the settings, the data store, the bearer token."""

from __future__ import annotations

import secrets
from typing import Annotated

from fastapi import Depends, HTTPException, Request

from server.records.store import DataStore
from server.service.errors import error
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


AUTH_MSG = "mutating endpoints need 'Authorization: Bearer <token>' (CUTWATCH_TOKEN)"


def authorised(request: Request, s: Config) -> None:
    """Refuse (401) a mutating request without ``Authorization: Bearer <CUTWATCH_TOKEN>``.

    No token configured (loopback only, see ``check_security``): every request passes.
    The token given is never echoed: ``got`` says only whether one was sent.
    """
    token = s.token.get_secret_value() if s.token is not None else ""
    if not token:
        return
    got = request.headers.get("authorization", "")
    if not secrets.compare_digest(got.encode(), f"Bearer {token}".encode()):
        found = "a credential that does not match" if got else "no Authorization header"
        raise HTTPException(
            401,
            detail=[error("authorization", "Bearer <CUTWATCH_TOKEN>", found, AUTH_MSG)],
            headers={"WWW-Authenticate": "Bearer"},
        )


#: route dependency of every mutating endpoint
Authorised = Depends(authorised)
