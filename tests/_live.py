"""A real uvicorn server on a free loopback port, for the API and WebSocket tests."""

from __future__ import annotations

import socket
import threading
import time
from collections.abc import Iterator
from contextlib import contextmanager

import uvicorn

from server.app import create_app
from server.commands.serve import WS_IMPL
from server.settings import Settings


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


@contextmanager
def serve(**settings: object) -> Iterator[str]:
    """Run the app in a background thread; yield its base URL; stop it cleanly."""
    port = free_port()
    app = create_app(Settings(port=port, **settings))  # type: ignore[arg-type]
    config = uvicorn.Config(
        app, host="127.0.0.1", port=port, ws=WS_IMPL, log_level="warning", lifespan="on"
    )
    server = uvicorn.Server(config)
    thread = threading.Thread(target=server.run, daemon=True)
    thread.start()
    deadline = time.monotonic() + 20
    while not server.started:
        if time.monotonic() > deadline or not thread.is_alive():
            raise RuntimeError("uvicorn did not start")
        time.sleep(0.02)
    try:
        yield f"127.0.0.1:{port}"
    finally:
        server.should_exit = True
        thread.join(10)
