"""A real Mosquitto broker for the tests: its own config file, a free loopback port.

``broker()`` starts ``mosquitto -c FILE`` (Debian's package; installed by ``make
system-deps`` when run as root) and stops it on exit. With ``users``, anonymous access is
off and a password file (made with ``mosquitto_passwd``) holds the users.
"""

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

import pytest

MOSQUITTO = shutil.which("mosquitto") or "/usr/sbin/mosquitto"
MOSQUITTO_PASSWD = shutil.which("mosquitto_passwd") or "/usr/bin/mosquitto_passwd"


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def need_mosquitto() -> None:
    if not Path(MOSQUITTO).exists():
        pytest.skip("mosquitto not installed (make system-deps installs it as root)")


@contextlib.contextmanager
def broker(users: dict[str, str] | None = None, port: int | None = None) -> Iterator[int]:
    """Run a broker; yields its port."""
    need_mosquitto()
    port = port or free_port()
    with tempfile.TemporaryDirectory(prefix="cutwatch-mosq-") as d:
        conf = Path(d) / "mosquitto.conf"
        lines = [
            f"listener {port} 127.0.0.1",
            "persistence false",
            # run as whoever started it (as root it would otherwise switch to the user
            # 'mosquitto', who cannot read this private temporary directory)
            f"user {getpass.getuser()}",
            "log_dest stderr",
            "log_type error",
            "log_type warning",
        ]
        if users:
            pw = Path(d) / "passwd"
            pw.touch()
            for u, p in users.items():
                subprocess.run([MOSQUITTO_PASSWD, "-b", str(pw), u, p], check=True)
            pw.chmod(0o600)
            lines += ["allow_anonymous false", f"password_file {pw}"]
        else:
            lines.append("allow_anonymous true")
        conf.write_text("\n".join(lines) + "\n")
        proc = subprocess.Popen(
            [MOSQUITTO, "-c", str(conf)], stdout=subprocess.DEVNULL, stderr=subprocess.PIPE
        )
        try:
            deadline = time.monotonic() + 10
            while True:
                try:
                    socket.create_connection(("127.0.0.1", port), timeout=0.2).close()
                    break
                except OSError:
                    if proc.poll() is not None or time.monotonic() > deadline:
                        err = proc.stderr.read().decode() if proc.stderr else ""
                        raise RuntimeError(f"mosquitto did not start on {port}: {err}") from None
                    time.sleep(0.05)
            yield port
        finally:
            proc.terminate()
            try:
                proc.wait(5)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait(5)
            if proc.stderr:
                proc.stderr.close()
