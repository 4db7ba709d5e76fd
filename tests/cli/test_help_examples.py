"""Every example in a command's ``--help`` runs, as written.

The examples are read from each sub-command's help text (its module docstring, the
``Examples::`` block), so an example added there is run here without anyone listing it.
Each runs as a real ``cutwatch`` process in a scratch directory, with only what belongs to
this machine put in: the broker address ``mqtt://127.0.0.1:1883`` of the examples points
to a real Mosquitto started for the test (``tests/_broker.py``), the OPC UA server
``opc.tcp://127.0.0.1:4840`` to a real ``cutwatch opcua-sim`` started for the test (offering
the secure policies and None, its certificate where the examples trust it), a port given on the
command line (``--port``) or taken by default (``CUTWATCH_PORT``, ``CUTWATCH_VISER_PORT``)
is a free one, and the data sets are linked where the examples expect it
(``DATA_EMPS.mat``, ``segments.csv``, ``../shared/data/...``; ``other.csv``, "another
table", is the same table), and so are the repository's example files
(``cnc-mill.json``). A finite command must exit 0
(``reproduce`` may exit 1 after reporting a check that does not hold, as its help says);
a server (``serve``, ``fleet``, ``worker``) must answer HTTP, ``opcua-sim`` accept a TCP
connection, then it is stopped.
"""

from __future__ import annotations

import os
import re
import shlex
import signal
import socket
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path

import httpx
import pytest
from _broker import broker, free_port

from server.cli import commands
from server.plugins import plugin_modules, short_name

pytestmark = pytest.mark.slow

EXAMPLE_BROKER = "mqtt://127.0.0.1:1883"
#: commands that serve until stopped, and the path that answers once they are up
SERVERS = {"serve": "/api/health", "fleet": "/", "worker": "/api/health", "opcua-sim": None}
EXAMPLE_OPCUA = "opc.tcp://127.0.0.1:4840"
SHARED_DATA = next(
    (p / "shared" / "data" for p in Path(__file__).resolve().parents if (p / "shared").is_dir()),
    None,
)
#: file named by an example in its current directory -> the data set file it stands for
#: (``other.csv``: "another table of the same form", the same one here)
DATA_LINKS = {
    "DATA_EMPS.mat": "emps/DATA_EMPS.mat",
    "segments.csv": "turning-wear/segments.csv",
    "other.csv": "turning-wear/segments.csv",
}
#: files of this repository an example names in its current directory (a machine's
#: description: docs/machine-description.md)
REPO_LINKS = {"cnc-mill.json": "docs/machines/cnc-mill.json"}
ROOT = Path(__file__).resolve().parents[2]


def examples(doc: str) -> list[str]:
    """The command lines of a help text's ``Examples::`` block (continuations joined,
    trailing ``# comments`` dropped)."""
    m = re.search(r"Examples?::\n\n((?:    .*\n|\n)+)", doc + "\n")
    if m is None:
        return []
    joined = re.sub(r"\\\n\s*", " ", m.group(1).strip())
    out = []
    for line in joined.splitlines():
        words = shlex.split(line.strip(), comments=True)
        if words:
            out.append(shlex.join(words))
    return out


def all_examples() -> list[tuple[str, str]]:
    """(command, example) of every sub-command; the ``simulate`` ones first (later
    examples read the ``run.csv`` they write)."""
    found = [
        (getattr(mod, "COMMAND", short_name(mod)), ex)
        for mod in plugin_modules(commands)
        for ex in examples(mod.__doc__ or "")
    ]
    return sorted(found, key=lambda c: c[1].split()[1:2] != ["simulate"])


EXAMPLES = all_examples()


def test_every_command_has_examples() -> None:
    names = {getattr(m, "COMMAND", short_name(m)) for m in plugin_modules(commands)}
    assert names - {c for c, _ in EXAMPLES} == set()


@pytest.fixture(scope="module")
def workdir(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """``root/work`` (the current directory of the examples), the data sets linked in."""
    root = tmp_path_factory.mktemp("examples")
    work = root / "work"
    (work / "web").mkdir(parents=True)  # the schema examples write web/schema.js
    for name, target in REPO_LINKS.items():
        (work / name).symlink_to(ROOT / target)
    if SHARED_DATA is not None:
        (root / "shared").mkdir()
        (root / "shared" / "data").symlink_to(SHARED_DATA)  # ../shared/data/... of the examples
        for name, target in DATA_LINKS.items():
            if (SHARED_DATA / target).exists():
                (work / name).symlink_to(SHARED_DATA / target)
    return work


@pytest.fixture(scope="module")
def broker_url() -> Iterator[str]:
    with broker() as port:
        yield f"mqtt://127.0.0.1:{port}"


@pytest.fixture(scope="module")
def opcua_url(workdir: Path) -> Iterator[str]:
    """A real ``cutwatch opcua-sim`` on a free port, run in the examples' directory (its
    certificate in ``data/opcua-sim``, where the examples trust it), with a starter map
    ``map.json`` browsed from it (what ``serve --nodes map.json`` reads)."""
    port = free_port()
    argv = [sys.executable, "-m", "server.cli.main", "opcua-sim", "--port", str(port)]
    proc = subprocess.Popen([*argv, "--security", "both"], cwd=workdir, stdout=subprocess.PIPE)
    try:
        assert accepts(port, proc), "opcua-sim did not start"
        url = f"opc.tcp://127.0.0.1:{port}"
        browse = ["opcua", "browse", f"{url}/cutwatch", "--out", "map.json"]
        trust = ["--opcua-trust", "data/opcua-sim/server-cert.der"]
        r = subprocess.run(
            [sys.executable, "-m", "server.cli.main", *browse, *trust],
            cwd=workdir, capture_output=True, timeout=120,
        )  # fmt: skip
        assert r.returncode == 0, r.stderr.decode()[-3000:]
        yield url
    finally:
        proc.send_signal(signal.SIGINT)
        try:
            proc.communicate(timeout=30)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.communicate()


def accepts(port: int, proc: subprocess.Popen[bytes], timeout: float = 90.0) -> bool:
    """Whether a TCP connection to ``port`` is accepted before ``timeout``."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline and proc.poll() is None:
        with socket.socket() as s:
            s.settimeout(2)
            if s.connect_ex(("127.0.0.1", port)) == 0:
                return True
        time.sleep(0.3)
    return False


def command_line(
    example: str, broker_url: str, opcua_url: str = EXAMPLE_OPCUA
) -> tuple[dict[str, str], list[str]]:
    """The example as environment and argv, this machine's broker, OPC UA server and
    ports put in."""
    env = dict(os.environ)
    env.update({"CUTWATCH_PORT": str(free_port()), "CUTWATCH_VISER_PORT": str(free_port())})
    # a `$(command)` is run as the user's shell would (the token examples: openssl rand)
    example = re.sub(
        r"\$\(([^)]*)\)",
        lambda m: subprocess.run(
            shlex.split(m.group(1)), check=True, capture_output=True, text=True
        ).stdout.strip(),
        example,
    )
    words = shlex.split(
        example.replace(EXAMPLE_BROKER, broker_url).replace(EXAMPLE_OPCUA, opcua_url)
    )
    while "=" in words[0]:  # VAR=value before the command
        key, _, value = words.pop(0).partition("=")
        env[key] = value
    assert words[0] == "cutwatch", example
    argv = [sys.executable, "-m", "server.cli.main", *words[1:]]
    if "--host" in argv:  # servers a test starts listen on loopback only (never 0.0.0.0)
        argv[argv.index("--host") + 1] = "127.0.0.1"
    if "--port" in argv:
        argv[argv.index("--port") + 1] = env["CUTWATCH_PORT"]
    return env, argv


def answers(port: int, path: str, proc: subprocess.Popen[bytes], timeout: float = 90.0) -> bool:
    """Whether the server on ``port`` answers ``path`` with 200 before ``timeout``."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline and proc.poll() is None:
        try:
            if httpx.get(f"http://127.0.0.1:{port}{path}", timeout=2).status_code == 200:
                return True
        except httpx.TransportError:
            pass
        time.sleep(0.3)
    return False


@pytest.mark.parametrize(("command", "example"), EXAMPLES, ids=[e for _, e in EXAMPLES])
def test_the_example_runs(
    command: str, example: str, workdir: Path, broker_url: str, request: pytest.FixtureRequest
) -> None:
    missing = [
        target
        for name, target in DATA_LINKS.items()
        if name in example and (SHARED_DATA is None or not (SHARED_DATA / target).exists())
    ]
    if missing:
        pytest.skip(f"data set not present: {', '.join(missing)}")
    opcua = request.getfixturevalue("opcua_url") if EXAMPLE_OPCUA in example else EXAMPLE_OPCUA
    env, argv = command_line(example, broker_url, opcua)
    command = argv[3]  # what the example runs (a help text may show other commands too)
    if command not in SERVERS:
        r = subprocess.run(argv, cwd=workdir, env=env, capture_output=True, timeout=1800)
        err = r.stderr.decode()[-3000:]
        if command == "reproduce" and r.returncode == 1:
            # ran to the end and reported a check that does not hold (its help says so)
            out = r.stdout.decode()
            assert "[FAIL]" in out or '"holds": false' in out, f"{example}\n{err}"
            assert "Traceback" not in err, f"{example}\n{err}"
            return
        assert r.returncode == 0, f"{example}\n{err}"
        return
    proc = subprocess.Popen(argv, cwd=workdir, env=env, stderr=subprocess.PIPE)
    port, path = int(env["CUTWATCH_PORT"]), SERVERS[command]
    try:
        up = answers(port, path, proc) if path is not None else accepts(port, proc)
    finally:
        proc.send_signal(signal.SIGINT)
        try:
            _, err = proc.communicate(timeout=30)
        except subprocess.TimeoutExpired:
            proc.kill()
            _, err = proc.communicate()
    assert up, f"{example}: no answer on {SERVERS[command]}\n{err.decode()[-3000:]}"
