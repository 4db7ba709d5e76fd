"""A real Mosquitto broker for the tests: its own config file, a free loopback port.

``broker()`` starts ``mosquitto -c FILE`` (Debian's package; installed by ``make
system-deps`` when run as root) and stops it on exit. With ``users``, anonymous access is
off and a password file (made with ``mosquitto_passwd``) holds the users; ``tls`` makes
its listener TLS (certificates from :func:`make_pki`, a certificate authority generated
for the test with ``openssl``); ``acl`` is an access list.
"""

from __future__ import annotations

import contextlib
import getpass
import shutil
import socket
import subprocess
import tempfile
import threading
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path

import pytest
from _proc import stop

MOSQUITTO = shutil.which("mosquitto") or "/usr/sbin/mosquitto"
MOSQUITTO_PASSWD = shutil.which("mosquitto_passwd") or "/usr/bin/mosquitto_passwd"


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


@contextlib.contextmanager
def silent_broker() -> Iterator[int]:
    """A port where a TCP listener takes connections and never answers (no CONNACK, no
    PUBACK): a broker that hangs. Whatever waits on the network there waits for good, so
    "never blocks" is judged by whether a call returns at all, not by how long it took."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        s.listen(16)
        yield int(s.getsockname()[1])


def returns(fn: Callable[[], object], deadline: float = 60.0) -> list[object]:
    """``[fn()]`` when it returned within ``deadline`` s, ``[]`` when it had not (or
    raised); run on a daemon thread, so one that hangs does not hold the test run."""
    out: list[object] = []
    th = threading.Thread(target=lambda: out.append(fn()), daemon=True)
    th.start()
    th.join(deadline)
    return out


def need_mosquitto() -> None:
    if not Path(MOSQUITTO).exists():
        pytest.skip("mosquitto not installed (make system-deps installs it as root)")


@dataclass(frozen=True)
class Pki:
    """A certificate authority made for one test run, its broker and client certificates,
    and a second, unrelated authority (whose certificates no one should accept)."""

    ca: Path
    server_cert: Path
    server_key: Path
    client_cert: Path  # CN "m1", signed by ``ca``
    client_key: Path
    rogue_ca: Path
    rogue_client_cert: Path  # CN "m1", signed by ``rogue_ca``
    rogue_client_key: Path


def _openssl(*args: str) -> None:
    subprocess.run(["openssl", *args], check=True, capture_output=True)


def _authority(d: Path, name: str) -> tuple[Path, Path]:
    crt, key = d / f"{name}.crt", d / f"{name}.key"
    _openssl(
        "req", "-x509", "-newkey", "ec", "-pkeyopt", "ec_paramgen_curve:P-256", "-nodes",
        "-keyout", str(key), "-out", str(crt), "-days", "2", "-subj", f"/CN={name}",
        "-addext", "basicConstraints=critical,CA:TRUE",
        "-addext", "keyUsage=critical,keyCertSign,cRLSign",
    )  # fmt: skip
    return crt, key


def _leaf(d: Path, name: str, cn: str, ca: tuple[Path, Path], ext: str) -> tuple[Path, Path]:
    crt, key, csr, extfile = (d / f"{name}.{x}" for x in ("crt", "key", "csr", "ext"))
    _openssl(
        "req", "-newkey", "ec", "-pkeyopt", "ec_paramgen_curve:P-256", "-nodes",
        "-keyout", str(key), "-out", str(csr), "-subj", f"/CN={cn}",
    )  # fmt: skip
    extfile.write_text(
        "basicConstraints=CA:FALSE\nauthorityKeyIdentifier=keyid\nsubjectKeyIdentifier=hash\n"
        + ext
        + "\n"
    )
    _openssl(
        "x509", "-req", "-in", str(csr), "-CA", str(ca[0]), "-CAkey", str(ca[1]),
        "-CAcreateserial", "-out", str(crt), "-days", "2", "-extfile", str(extfile),
    )  # fmt: skip
    return crt, key


def make_pki(d: Path) -> Pki:
    """Generate the authorities and certificates in ``d`` (openssl, EC P-256, 2 days)."""
    if not shutil.which("openssl"):
        pytest.skip("openssl not installed")
    d.mkdir(parents=True, exist_ok=True)
    ca = _authority(d, "ca")
    rogue = _authority(d, "rogue-ca")
    server = _leaf(
        d, "server", "localhost", ca,
        "subjectAltName=DNS:localhost,IP:127.0.0.1\nextendedKeyUsage=serverAuth",
    )  # fmt: skip
    client = _leaf(d, "client", "m1", ca, "extendedKeyUsage=clientAuth")
    rogue_client = _leaf(d, "rogue-client", "m1", rogue, "extendedKeyUsage=clientAuth")
    return Pki(ca[0], *server, *client, rogue[0], *rogue_client)


def tls_listener(pki: Pki, *, require_certificate: bool = False) -> list[str]:
    """The lines of a TLS listener (after its ``listener`` line) using ``pki``."""
    lines = [f"cafile {pki.ca}", f"certfile {pki.server_cert}", f"keyfile {pki.server_key}"]
    if require_certificate:
        lines += ["require_certificate true", "use_identity_as_username true"]
    return lines


def password_file(path: Path, users: dict[str, str]) -> Path:
    """A Mosquitto password file holding ``users`` (made with ``mosquitto_passwd``)."""
    path.touch()
    for u, p in users.items():
        subprocess.run([MOSQUITTO_PASSWD, "-b", str(path), u, p], check=True)
    path.chmod(0o600)
    return path


@contextlib.contextmanager
def broker(
    users: dict[str, str] | None = None,
    port: int | None = None,
    *,
    tls: list[str] | None = None,
    acl: str | None = None,
) -> Iterator[int]:
    """Run a broker; yields its port.

    ``tls``: the listener's TLS lines (:func:`tls_listener`); ``acl``: the text of an
    access-list file.
    """
    need_mosquitto()
    with tempfile.TemporaryDirectory(prefix="cutwatch-mosq-") as d:
        port = port or free_port()
        lines = [f"listener {port} 127.0.0.1", *(tls or [])]
        if users:
            pw = password_file(Path(d) / "passwd", users)
            lines += ["allow_anonymous false", f"password_file {pw}"]
        elif tls and any(x.startswith("use_identity_as_username") for x in tls):
            lines.append("allow_anonymous false")
        else:
            lines.append("allow_anonymous true")
        if acl is not None:
            (Path(d) / "acl").write_text(acl)
            lines.append(f"acl_file {Path(d) / 'acl'}")
        with mosquitto(lines, port, Path(d)):
            yield port


@contextlib.contextmanager
def mosquitto(lines: list[str], port: int, d: Path) -> Iterator[None]:
    """Run ``mosquitto`` with ``lines`` (plus the test settings) as its configuration, in
    directory ``d``; wait until it listens on ``port``; stop it on exit."""
    need_mosquitto()
    conf = d / "mosquitto.conf"
    base = [
        "persistence false",
        # run as whoever started it (as root it would otherwise switch to the user
        # 'mosquitto', who cannot read this private temporary directory)
        f"user {getpass.getuser()}",
        "log_dest stderr",
        "log_type error",
        "log_type warning",
    ]
    conf.write_text("\n".join(base + lines) + "\n")
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
        yield
    finally:
        stop(proc, 5)
