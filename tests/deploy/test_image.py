"""The container image, built by ``make image``'s script and run with buildah.

Builds ``cutwatch:latest`` from the Dockerfile (deploy/build-image.sh: a local
debian:bookworm-slim from debootstrap, then ``buildah bud``), starts the image's own
entrypoint in a working container on free loopback ports and checks what a user of the
image relies on: a non-root ``cutwatch serve``, health over real HTTP, the WebSocket stream,
the viser view through /viser/, slow clients dropped, the image's HEALTHCHECK command, the
token that binding 0.0.0.0 demands, and a clean stop on SIGTERM (what ``docker stop``
sends).

Chroot isolation shares the host's network, so the entrypoint's ``--host 0.0.0.0`` is
followed by ``--host 127.0.0.1`` (the last one wins): nothing listens beyond loopback.
Needs root (buildah's vfs storage); marked ``image``, run by ``make test-image``.
"""

from __future__ import annotations

import json
import os
import secrets
import signal
import socket
import subprocess
import time
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import httpx
import pytest
from websockets.sync.client import connect

pytestmark = pytest.mark.image

ROOT = Path(__file__).resolve().parents[2]
IMAGE = "cutwatch:latest"
BUILD_TIMEOUT_S = 40 * 60
START_TIMEOUT_S = 180.0
STOP_TIMEOUT_S = 30.0


def buildah(*args: str, timeout: float = 120, **env: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        ["buildah", "--storage-driver", "vfs", *args],
        capture_output=True,
        text=True,
        timeout=timeout,
        env={**os.environ, **env},
        check=False,
    )


def run_in(
    ctr: str, cmd: list[str], *, env: dict[str, str] | None = None, timeout: float = 120
) -> subprocess.CompletedProcess[str]:
    """``buildah run`` a command in the working container; the completed process."""
    flags = [f"--env={k}={v}" for k, v in (env or {}).items()]
    return buildah("run", "--isolation", "chroot", *flags, ctr, "--", *cmd, timeout=timeout)


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def children(pid: int) -> list[int]:
    """The processes whose parent is ``pid`` (from /proc/*/stat)."""
    out = []
    for entry in Path("/proc").iterdir():
        if not entry.name.isdigit():
            continue
        try:
            stat = (entry / "stat").read_text()
        except OSError:
            continue
        # the fields after the command name, which is in parentheses and may hold spaces
        fields = stat[stat.rindex(")") + 2 :].split()
        if int(fields[1]) == pid:
            out.append(int(entry.name))
    return out


def cmdline(pid: int) -> str:
    try:
        return (Path("/proc") / str(pid) / "cmdline").read_bytes().replace(b"\0", b" ").decode()
    except OSError:
        return ""


def find_service(runner: int) -> int | None:
    """The service: the innermost process under ``buildah run`` (runtime, exec, python)."""
    pid = runner
    while kids := children(pid):
        pid = kids[0]
    if pid != runner and "buildah" not in cmdline(pid) and "cutwatch" in cmdline(pid):
        return pid
    return None


@pytest.fixture(scope="module")
def config() -> dict[str, Any]:
    """Build the image (as ``make image`` does); its Docker config (``buildah inspect``)."""
    build = subprocess.run(
        [str(ROOT / "deploy" / "build-image.sh")],
        capture_output=True,
        text=True,
        timeout=BUILD_TIMEOUT_S,
        check=False,
    )
    if build.returncode != 0:
        pytest.fail(
            f"deploy/build-image.sh failed:\n{build.stdout[-3000:]}\n{build.stderr[-3000:]}"
        )
    inspect = buildah("inspect", "--type", "image", IMAGE)
    assert inspect.returncode == 0, inspect.stderr
    cfg: dict[str, Any] = json.loads(inspect.stdout)["Docker"]["config"]
    return cfg


@pytest.fixture(scope="module")
def ctr(config: dict[str, Any]) -> Iterator[str]:
    """A working container of the image, removed afterwards."""
    made = buildah("from", "--pull-never", IMAGE)
    assert made.returncode == 0, made.stderr
    name = made.stdout.strip().splitlines()[-1]
    try:
        yield name
    finally:
        buildah("rm", name)


@dataclass
class Service:
    runner: subprocess.Popen[str]
    pid: int
    port: int
    viser_port: int
    token: str
    log: Path

    @property
    def url(self) -> str:
        return f"http://127.0.0.1:{self.port}"

    def env(self) -> dict[str, str]:
        return {"CUTWATCH_PORT": str(self.port), "CUTWATCH_VISER_PORT": str(self.viser_port)}


@pytest.fixture(scope="module")
def service(
    config: dict[str, Any], ctr: str, tmp_path_factory: pytest.TempPathFactory
) -> Iterator[Service]:
    """The image's entrypoint running in ``ctr`` with a token, on free loopback ports."""
    port, viser_port = free_port(), free_port()
    token = secrets.token_urlsafe(18)
    log = tmp_path_factory.mktemp("image") / "serve.log"
    env = {
        "CUTWATCH_TOKEN": token,
        "CUTWATCH_PORT": str(port),
        "CUTWATCH_VISER_PORT": str(viser_port),
    }
    cmd = [*config["Entrypoint"], "--host", "127.0.0.1", "--log-level", "info"]
    flags = [f"--env={k}={v}" for k, v in env.items()]
    run = ["buildah", "--storage-driver", "vfs", "run", "--isolation", "chroot", *flags, ctr]
    with log.open("w") as out:
        runner = subprocess.Popen(
            [*run, "--", *cmd],
            stdout=out,
            stderr=subprocess.STDOUT,
            text=True,
            start_new_session=True,  # its own signals only: the test stops the service itself
        )
    try:
        pid = None
        deadline = time.monotonic() + START_TIMEOUT_S
        while time.monotonic() < deadline and runner.poll() is None:
            pid = pid or find_service(runner.pid)
            try:
                if httpx.get(f"http://127.0.0.1:{port}/api/health", timeout=2).status_code == 200:
                    break
            except httpx.TransportError:
                pass
            time.sleep(0.5)
        else:
            pytest.fail(
                f"the service did not answer within {START_TIMEOUT_S} s:\n{log.read_text()}"
            )
        pid = pid or find_service(runner.pid)
        assert pid is not None, "no service process found under buildah run"
        yield Service(runner, pid, port, viser_port, token, log)
    finally:
        if runner.poll() is None:
            service_pid = find_service(runner.pid)
            if service_pid is not None:
                os.kill(service_pid, signal.SIGTERM)
            try:
                runner.wait(STOP_TIMEOUT_S)
            except subprocess.TimeoutExpired:
                os.killpg(runner.pid, signal.SIGKILL)
                runner.wait(10)


def test_image_config(config: dict[str, Any], ctr: str) -> None:
    assert config["User"] == "cutwatch"
    assert config["Entrypoint"] == ["cutwatch", "serve", "--host", "0.0.0.0"]
    assert set(config["ExposedPorts"]) == {"8000/tcp"}  # viser: loopback, through /viser/
    test = config["Healthcheck"]["Test"]
    assert test[0] == "CMD" and any("/api/health" in part for part in test)
    # the final stage has neither a compiler nor the installers
    found = run_in(ctr, ["sh", "-c", "command -v gcc cc c++ pip pip3 npm node; true"])
    assert found.returncode == 0 and found.stdout.strip() == "", found.stdout


def test_refuses_to_start_without_a_token(config: dict[str, Any], ctr: str) -> None:
    # the image's entrypoint as it is (binding 0.0.0.0): it stops before binding anything
    ran = run_in(ctr, config["Entrypoint"], env={"CUTWATCH_PORT": str(free_port())}, timeout=180)
    assert ran.returncode != 0
    assert "requires a bearer token" in ran.stdout + ran.stderr


def test_serves_as_a_non_root_user(service: Service, ctr: str) -> None:
    assert "cutwatch serve" in cmdline(service.pid)
    uids = (Path("/proc") / str(service.pid) / "status").read_text().split("Uid:")[1].split()[:4]
    image_uid = run_in(ctr, ["id", "-u", "cutwatch"]).stdout.strip()
    assert image_uid.isdigit() and int(image_uid) != 0
    assert uids == [image_uid] * 4  # real, effective, saved, file-system


def test_health_and_dashboard_over_http(service: Service) -> None:
    health = httpx.get(f"{service.url}/api/health", timeout=5).json()
    # the default machine (the centre) runs degraded by design: the stage's observers cannot
    # run on it and say why; the container is healthy while the loop runs and estimates
    assert health["status"] in ("ok", "degraded") and health["loop_error"] is None
    assert health["idle"] == "" and any(p["running"] for p in health["parts"])
    assert all(p["reason"] for p in health["parts"] if not p["running"])
    assert health["viser_running"] is True and health["viser_port"] == service.viser_port
    auth = {"Authorization": f"Bearer {service.token}"}  # every read but health needs it
    assert httpx.get(f"{service.url}/", timeout=5).status_code == 401
    page = httpx.get(f"{service.url}/", headers=auth, timeout=5)
    assert page.status_code == 200 and "/vendor/uplot/uPlot.iife.min.js" in page.text
    # the uPlot asset copied from the image's npm stage
    uplot = httpx.get(f"{service.url}/vendor/uplot/uPlot.iife.min.js", headers=auth, timeout=5)
    assert uplot.status_code == 200 and "uPlot" in uplot.text


def test_ws_streams_hello_and_data(service: Service) -> None:
    auth = {"Authorization": f"Bearer {service.token}"}
    with connect(f"ws://127.0.0.1:{service.port}/ws", additional_headers=auth) as ws:
        hello = json.loads(ws.recv(timeout=10))
        frames = [json.loads(ws.recv(timeout=10)) for _ in range(5)]
    assert hello["type"] == "hello" and hello["channels"]
    assert all(f["type"] == "data" and f["ch"] for f in frames)
    seqs = [f["seq"] for f in frames]
    assert seqs == list(range(seqs[0], seqs[0] + 5))


def test_viser_answers_through_the_app(service: Service) -> None:
    auth = {"Authorization": f"Bearer {service.token}"}
    page = httpx.get(f"{service.url}/viser/", headers=auth, timeout=10)
    assert page.status_code == 200 and "<html" in page.text.lower()
    assert httpx.get(f"{service.url}/viser/", timeout=10).status_code == 401


def test_healthcheck_command_passes(config: dict[str, Any], service: Service, ctr: str) -> None:
    ran = run_in(ctr, config["Healthcheck"]["Test"][1:], env=service.env())
    assert ran.returncode == 0, ran.stdout + ran.stderr


def test_records_into_the_image_data_directory(service: Service) -> None:
    # the data directory (CUTWATCH_DATA_DIR) is writable by the service's user
    auth = {"Authorization": f"Bearer {service.token}"}
    url = f"{service.url}/api/record"
    start = httpx.post(url, json={"action": "start", "name": "img"}, headers=auth, timeout=5)
    assert start.status_code == 200, start.text
    time.sleep(1.0)
    stop = httpx.post(url, json={"action": "stop"}, headers=auth, timeout=5)
    assert stop.status_code == 200, stop.text
    deadline = time.monotonic() + 10
    names: list[str] = []
    while time.monotonic() < deadline and not names:
        listing = httpx.get(f"{service.url}/api/records", headers=auth, timeout=5).json()
        listing = listing["records"]
        names = [r["name"] for r in listing if not r["active"]]
        time.sleep(0.2)
    assert any(n.startswith("img") for n in names), names


def test_requests_need_the_token(service: Service) -> None:
    assert httpx.get(f"{service.url}/api/params", timeout=5).status_code == 401
    url = f"{service.url}/api/control"
    pause = {"action": "pause"}
    assert httpx.post(url, json=pause, timeout=5).status_code == 401
    wrong = {"Authorization": "Bearer not-the-token"}
    assert httpx.post(url, json=pause, headers=wrong, timeout=5).status_code == 401
    assert httpx.get(f"{service.url}/api/health", timeout=5).json()["paused"] is False
    right = {"Authorization": f"Bearer {service.token}"}
    assert httpx.post(url, json=pause, headers=right, timeout=5).status_code == 200
    assert httpx.get(f"{service.url}/api/health", timeout=5).json()["paused"] is True
    assert httpx.post(url, json={"action": "resume"}, headers=right, timeout=5).status_code == 200


def test_slow_clients_are_dropped(service: Service) -> None:
    """The image's ``cutwatch serve`` has the HTTP limits (server/service/http_guard.py):
    half a request line is answered 408 and closed at the default 10 s, not before; a
    10 MiB header is refused with 431 long before it is all sent.

    When the 408 came is judged against what cannot race: the clock starts before the
    connection, so before the server's timer, and the drop is never earlier than the
    limit (less the timer clock's whole millisecond); the answer names the 10 s. No upper
    bound on a loaded machine's lateness: without the limits uvicorn holds such a
    connection for as long as the client likes, which the socket's 60 s timeout catches."""
    t0 = time.monotonic()
    with socket.create_connection(("127.0.0.1", service.port), timeout=60) as s:
        s.sendall(b"GET /api/hea")
        raw = b""
        while chunk := s.recv(4096):
            raw += chunk
        took = time.monotonic() - t0
    assert raw.startswith(b"HTTP/1.1 408"), (took, raw[:200])
    assert b"request headers not complete within 10 s" in raw, raw[:400]
    assert took >= 10.0 - 0.01, took
    with socket.create_connection(("127.0.0.1", service.port), timeout=15) as s:
        s.sendall(b"GET /api/health HTTP/1.1\r\nHost: 127.0.0.1\r\nX-Big: ")
        sent = 0
        try:
            while sent < 10 * 2**20:
                sent += s.send(b"a" * 65536)
        except OSError:
            pass
        raw = s.recv(4096)
    assert raw.startswith(b"HTTP/1.1 431") and sent < 10 * 2**20, (sent, raw[:200])


def test_stops_cleanly_on_sigterm(config: dict[str, Any], service: Service, ctr: str) -> None:
    # last in this module: what `docker stop` does, SIGTERM to the service
    os.kill(service.pid, signal.SIGTERM)
    service.runner.wait(STOP_TIMEOUT_S)
    log = service.log.read_text()
    assert "Application shutdown complete" in log, log
    assert "Traceback" not in log, log
    assert not Path(f"/proc/{service.pid}").exists()
    for port in (service.port, service.viser_port):
        with socket.socket() as s, pytest.raises(ConnectionRefusedError):
            s.connect(("127.0.0.1", port))
    # and the HEALTHCHECK command now reports it
    ran = run_in(ctr, config["Healthcheck"]["Test"][1:], env=service.env())
    assert ran.returncode != 0
