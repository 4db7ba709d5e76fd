"""A real uvicorn server on a free loopback port, for the API and WebSocket tests."""

from __future__ import annotations

import os
import signal
import socket
import subprocess
import sys
import tempfile
import threading
import time
import urllib.request
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import uvicorn

from server.pipeline.broker import BrokerConfig
from server.service.app import create_app
from server.service.front import uvicorn_options
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


class ServeProcess:
    """``cutwatch serve`` (or ``command``: ``fleet``) as a child process on a free loopback
    port (see :func:`serve_process`); ``stop(sig)`` ends it with that signal and waits."""

    def __init__(self, args: list[str], env: dict[str, str], command: str = "serve") -> None:
        sock = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
        sock.bind(("127.0.0.1", 0))
        self.port = int(sock.getsockname()[1])
        sock.close()  # the child binds it again (a race with other binders is unlikely)
        self.host = f"127.0.0.1:{self.port}"
        cmd = [sys.executable, "-m", "server.cli.main", command, "--port", str(self.port)]
        if command == "serve":
            cmd.append("--no-viser")
        # the child's output goes to a file, not a pipe: a pipe nobody reads fills up (64 KiB)
        # and then blocks the server's logging, and with it the server
        self._log = tempfile.TemporaryFile(mode="w+")
        self.proc = subprocess.Popen(
            [*cmd, *args],
            env={**os.environ, **env},
            stdout=self._log,
            stderr=subprocess.STDOUT,
            text=True,
        )
        self.stderr = ""

    def output(self) -> str:
        """What the child has written so far (stdout and stderr)."""
        self._log.flush()
        self._log.seek(0)
        return self._log.read()

    def wait_ready(self, timeout: float = 60.0) -> None:
        """Until ``GET /api/health`` answers (AssertionError when the child exits)."""
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            if self.proc.poll() is not None:
                self.proc.wait()
                raise AssertionError(f"cutwatch exited: {self.output()[-3000:]}")
            try:
                with urllib.request.urlopen(f"http://{self.host}/api/health", timeout=2):
                    return
            except OSError:
                time.sleep(0.2)
        raise AssertionError("cutwatch did not answer in time")

    @property
    def base(self) -> str:
        return f"http://{self.host}"

    def rss_kb(self, key: str = "VmRSS") -> int:
        """A memory figure of the process from /proc (VmRSS, VmHWM: the peak) [kB]."""
        for line in Path(f"/proc/{self.proc.pid}/status").read_text().splitlines():
            if line.startswith(key + ":"):
                return int(line.split()[1])
        raise KeyError(key)

    def reset_peak(self) -> None:
        """Reset VmHWM to the current RSS (Linux: 5 > /proc/PID/clear_refs)."""
        Path(f"/proc/{self.proc.pid}/clear_refs").write_text("5")

    def stop(self, sig: int = signal.SIGTERM, timeout: float = 30.0) -> int:
        """Send ``sig``, wait for the exit, keep stderr; the exit code."""
        if self.proc.poll() is None:
            self.proc.send_signal(sig)
        try:
            self.proc.wait(timeout=timeout)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            self.proc.wait()
        self.stderr = self.output()
        return int(self.proc.returncode)


@contextmanager
def serve_process(*args: str, **env: str) -> Iterator[ServeProcess]:
    """Run ``cutwatch serve <args>`` (environment ``env`` added), ready; killed at exit
    if still running."""
    with _process("serve", args, env) as sp:
        yield sp


@contextmanager
def fleet_process(*args: str, **env: str) -> Iterator[ServeProcess]:
    """Run ``cutwatch fleet <args>`` (environment ``env`` added), ready; killed at exit."""
    with _process("fleet", args, env) as sp:
        yield sp


@contextmanager
def _process(command: str, args: tuple[str, ...], env: dict[str, str]) -> Iterator[ServeProcess]:
    sp = ServeProcess(list(args), dict(env), command)
    try:
        sp.wait_ready()
        yield sp
    finally:
        if sp.proc.poll() is None:
            sp.stop(signal.SIGKILL)
        sp._log.close()


@contextmanager
def serve_fleet(
    cfg: BrokerConfig, stale_after: float = 1.0, *, settings: Settings | None = None,
    links: Any = None,
) -> Iterator[str]:  # fmt: skip
    """The fleet page on ``cfg``'s broker in a background thread (``links``: a
    ``server.service.fleet.Links``); yield ``host:port``."""
    from server.service.fleet import create_fleet_app

    with serve_asgi(create_fleet_app(cfg, stale_after, settings, links), settings) as hp:
        yield hp


@contextmanager
def serve_asgi(app: Any, settings: Settings | None = None) -> Iterator[str]:
    """Any of cutwatch's apps (the fleet page's, a worker's) on a free loopback port in a
    background thread, run as its command runs it (``uvicorn_options``); ``host:port``."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = int(s.getsockname()[1])
    options = uvicorn_options(settings if settings is not None else Settings())
    del options["workers"]
    config = uvicorn.Config(app, host="127.0.0.1", port=port, log_level="error", **options)  # type: ignore[arg-type]
    with in_thread(uvicorn.Server(config)):
        yield f"127.0.0.1:{port}"
