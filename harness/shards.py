"""Which worker owns which machine: a stable hash of the name, modulo the shard count.

A plant's machines are spread over ``N`` workers (``cutwatch worker --shard I/N``): the
machine named ``m`` belongs to shard ``shard_of(m, N)``. The hash is the first 8 bytes of
the name's SHA-256 (big-endian), not Python's ``hash()``, which is salted per process
(``PYTHONHASHSEED``): two workers, or one worker before and after a restart, would
disagree on who owns a machine. The same name gives the same shard on every host,
version and run.

Why not MQTT shared subscriptions (``$share/group/cutwatch/+/drive``): the broker hands a
shared subscription's messages out one by one to the group's members (round robin, or
whichever is free), so one machine's consecutive drive blocks would land on different
workers; each worker would see every machine with holes in its feed, and no worker would
hold the whole state (observers, identifiers, wear) of any machine. A machine's blocks
must all reach the one process that holds its state: a fixed owner per machine.
"""

from __future__ import annotations

import hashlib
import re
import socket

from common.errors import ParameterError

_SHARD_RE = re.compile(r"(\d+|host)/(\d+)")


def shard_of(machine: str, shards: int) -> int:
    """The shard (0 .. ``shards`` - 1) that owns ``machine``."""
    if shards < 1:
        raise ParameterError("shards", "an integer >= 1", shards)
    digest = hashlib.sha256(machine.encode("utf-8")).digest()
    return int.from_bytes(digest[:8], "big") % shards


def host_ordinal(hostname: str | None = None) -> int:
    """The ordinal at the end of the host name (``cutwatch-worker-3`` -> 3): a Kubernetes
    StatefulSet's pod is named ``<set>-<ordinal>`` and that is its host name.

    Raises
    ------
    ParameterError
        The host name does not end in ``-<digits>``.
    """
    name = hostname if hostname is not None else socket.gethostname()
    m = re.search(r"-(\d+)$", name)
    if m is None:
        raise ParameterError(
            "--shard host/N", "a host name ending in -<ordinal> (a StatefulSet's pod)", name
        )
    return int(m.group(1))


def parse_shard(text: str, hostname: str | None = None) -> tuple[int, int]:
    """``"I/N"`` (or ``"host/N"``: I from the host name's ordinal) -> ``(I, N)``.

    Raises
    ------
    ParameterError
        Not ``I/N`` with 0 <= I < N (named: ``--shard``, expected and found).
    """
    m = _SHARD_RE.fullmatch(text.strip())
    if m is None:
        raise ParameterError("--shard", "I/N with integers 0 <= I < N, or host/N", text)
    n = int(m.group(2))
    i = host_ordinal(hostname) if m.group(1) == "host" else int(m.group(1))
    if not 0 <= i < n:
        raise ParameterError(
            "--shard", f"0 <= I < N (N = {n})", text if m.group(1) != "host" else i
        )
    return i, n


def owns(machine: str, shard: tuple[int, int] | None, machines: frozenset[str] | None) -> bool:
    """Whether a worker of ``shard`` (or of the explicit list ``machines``) owns ``machine``."""
    if machines is not None:
        return machine in machines
    assert shard is not None
    return shard_of(machine, shard[1]) == shard[0]
