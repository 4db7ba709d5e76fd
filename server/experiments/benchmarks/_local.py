"""What the benchmarks that start real parts share: a free loopback port, a Mosquitto of
their own on it."""

from __future__ import annotations

import contextlib
import getpass
import shutil
import socket
import subprocess
import tempfile
import time
from collections.abc import Iterator
from pathlib import Path


def free_port() -> int:
    """A TCP port free on 127.0.0.1 now."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


@contextlib.contextmanager
def mosquitto(port: int) -> Iterator[subprocess.Popen[bytes]]:
    """A Mosquitto on ``127.0.0.1:port`` with its own config (anonymous, no persistence),
    answering before this yields; stopped on exit."""
    exe = shutil.which("mosquitto") or "/usr/sbin/mosquitto"
    if not Path(exe).exists():
        raise RuntimeError("mosquitto is not installed (make system-deps installs it as root)")
    with tempfile.TemporaryDirectory(prefix="cutwatch-bench-mosq-") as d:
        conf = Path(d) / "mosquitto.conf"
        conf.write_text(
            f"listener {port} 127.0.0.1\nallow_anonymous true\npersistence false\n"
            f"user {getpass.getuser()}\nlog_dest none\n"
        )
        # its output (as root: a warning at start) to our stderr: a --json run prints one
        # document on stdout, and nothing of a child's
        p = subprocess.Popen([exe, "-c", str(conf)], stdout=2, stderr=2)
        try:
            deadline = time.monotonic() + 10
            while True:
                try:
                    socket.create_connection(("127.0.0.1", port), timeout=0.2).close()
                    break
                except OSError:
                    if p.poll() is not None or time.monotonic() > deadline:
                        raise RuntimeError(f"mosquitto did not start on {port}") from None
                    time.sleep(0.05)
            yield p
        finally:
            p.terminate()
            p.wait(10)
