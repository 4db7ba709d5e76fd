"""A real uvicorn server on a free loopback port, for the API and WebSocket tests."""

from __future__ import annotations

import socket
import tempfile
import threading
import time
from collections.abc import Iterator
from contextlib import contextmanager

import uvicorn

from server.cli.commands.serve import uvicorn_options
from server.service.app import create_app
from server.service.settings import Settings

#: test tokens of the two roles (CUTWATCH_TOKEN, CUTWATCH_VIEW_TOKEN: 16 characters at least)
OPERATOR = "operator-token-for-tests"
VIEWER = "viewer-token-for-tests"


@contextmanager
def serve(*, sndbuf: int | None = None, **settings: object) -> Iterator[str]:
    """Run the app in a background thread; yield ``host:port``; stop it cleanly.

    ``sndbuf`` shrinks the kernel send buffer of the accepted sockets (Linux inherits it
    from the listening socket), so that a client that never reads fills the pipe quickly.
    """
    sock = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
    sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
    if sndbuf is not None:
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_SNDBUF, sndbuf)
    sock.bind(("127.0.0.1", 0))
    port = int(sock.getsockname()[1])
    settings.setdefault("viser", False)  # tests start viser only where they mean to
    # the service's data areas in a temporary directory, never ./data of the checkout
    tmp = None
    if "data_dir" not in settings:
        tmp = tempfile.TemporaryDirectory(prefix="cutwatch-data-")
        settings["data_dir"] = tmp.name
    try:
        s = Settings(port=port, **settings)  # type: ignore[arg-type]
        app = create_app(s)
    except BaseException:
        sock.close()
        if tmp is not None:
            tmp.cleanup()
        raise
    options = uvicorn_options(s)
    del options["workers"]  # one server in this thread
    config = uvicorn.Config(
        app,
        host="127.0.0.1",
        port=port,
        log_level="warning",
        **options,  # type: ignore[arg-type]
    )
    server = uvicorn.Server(config)
    thread = threading.Thread(target=server.run, kwargs={"sockets": [sock]}, daemon=True)
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
        sock.close()
        if tmp is not None:
            tmp.cleanup()
