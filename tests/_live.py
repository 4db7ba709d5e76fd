"""A real uvicorn server on a free loopback port, for the API and WebSocket tests; and
``cutwatch serve`` as its own process, where the test measures the service itself."""

from __future__ import annotations

import os
import socket
import subprocess
import sys
import tempfile
import threading
import time
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path

import httpx
import uvicorn

from server.cli.commands.serve import uvicorn_options
from server.pipeline.broker import BrokerConfig
from server.service.app import create_app
from server.service.settings import Settings

#: test tokens of the two roles (CUTWATCH_TOKEN, CUTWATCH_VIEW_TOKEN: 16 characters at least)
OPERATOR = "operator-token-for-tests"
VIEWER = "viewer-token-for-tests"


@contextmanager
def in_thread(server: uvicorn.Server, sock: socket.socket | None = None) -> Iterator[None]:
    """Run ``server`` (on ``sock`` if given) in a daemon thread until the block ends."""
    kwargs = {"sockets": [sock]} if sock is not None else {}
    thread = threading.Thread(target=server.run, kwargs=kwargs, daemon=True)
    thread.start()
    deadline = time.monotonic() + 20
    while not server.started:
        if time.monotonic() > deadline or not thread.is_alive():
            raise RuntimeError("uvicorn did not start")
        time.sleep(0.02)
    try:
        yield
    finally:
        server.should_exit = True
        thread.join(10)


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
    try:
        with in_thread(uvicorn.Server(config), sock):
            yield f"127.0.0.1:{port}"
    finally:
        sock.close()
        if tmp is not None:
            tmp.cleanup()


@dataclass
class Process:
    """A ``cutwatch serve`` process: its Popen, base URL and the file its stderr goes to."""

    proc: subprocess.Popen[bytes]
    base: str
    log: Path

    def rss_kb(self, key: str = "VmRSS") -> int:
        """A memory figure of the process from /proc (VmRSS, VmHWM: the peak) [kB]."""
        for line in Path(f"/proc/{self.proc.pid}/status").read_text().splitlines():
            if line.startswith(key + ":"):
                return int(line.split()[1])
        raise KeyError(key)

    def reset_peak(self) -> None:
        """Reset VmHWM to the current RSS (Linux: 5 > /proc/PID/clear_refs)."""
        Path(f"/proc/{self.proc.pid}/clear_refs").write_text("5")


@contextmanager
def serve_process(data_dir: Path, log: Path, **env: str) -> Iterator[Process]:
    """Run ``cutwatch serve`` as its own process on a free loopback port (no viser), the
    data areas in ``data_dir``; ``env`` adds ``CUTWATCH_*`` variables. Stops it (SIGTERM)
    unless the test has ended it already."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = int(s.getsockname()[1])
    cmd = [sys.executable, "-c", "from server.cli.main import main; raise SystemExit(main())",
           "serve", "--port", str(port), "--no-viser", "--data-dir", str(data_dir)]  # fmt: skip
    full = {k: v for k, v in os.environ.items() if not k.startswith("CUTWATCH_")}
    full.update(env)
    with log.open("ab") as err:
        proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=err, env=full)
    base = f"http://127.0.0.1:{port}"
    try:
        deadline = time.monotonic() + 60
        while True:
            if proc.poll() is not None:
                raise RuntimeError(f"cutwatch serve exited: {log.read_text()[-2000:]}")
            try:
                if httpx.get(f"{base}/api/health", timeout=2).status_code == 200:
                    break
            except httpx.HTTPError:
                pass
            if time.monotonic() > deadline:
                raise RuntimeError("cutwatch serve did not answer within 60 s")
            time.sleep(0.2)
        yield Process(proc, base, log)
    finally:
        if proc.poll() is None:
            proc.terminate()
            try:
                proc.wait(20)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait()


@contextmanager
def serve_fleet(cfg: BrokerConfig, stale_after: float = 1.0) -> Iterator[str]:
    """The fleet page on ``cfg``'s broker in a background thread; yield ``host:port``."""
    from server.service.fleet import create_fleet_app
    from server.service.http_guard import GuardedHttpToolsProtocol

    app = create_fleet_app(cfg, stale_after)
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = int(s.getsockname()[1])
    config = uvicorn.Config(
        app, host="127.0.0.1", port=port, log_level="error", http=GuardedHttpToolsProtocol
    )
    with in_thread(uvicorn.Server(config)):
        yield f"127.0.0.1:{port}"
