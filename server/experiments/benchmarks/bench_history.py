"""The kept history's cost per committed write: one event per transaction, as the live loop
writes a block's events, on SQLite with ``synchronous=FULL`` (the service's: an fsync of
the write-ahead log per commit) and, side by side, ``NORMAL`` (no fsync per commit; what
FULL buys is the last commits over a power cut). Also an acknowledgement's (FULL).

The files lie in the system's temporary directory: run it where it is on the same kind
of disk as the service's data directory (``TMPDIR``).
"""

from __future__ import annotations

import statistics
import tempfile
import time
from pathlib import Path
from typing import Any

from server.experiments.benchmarks import Figures


def _stats(name: str, xs: list[float]) -> dict[str, float]:
    v = sorted(xs)
    n = len(v)
    return {
        f"{name}_median_ms": 1e3 * statistics.median(v),
        f"{name}_p95_ms": 1e3 * v[min(n - 1, int(0.95 * n))],
        f"{name}_p99_ms": 1e3 * v[min(n - 1, int(0.99 * n))],
    }


def measure(*, repeats: int, quick: bool) -> Figures:
    """Per-write wall times [ms] (median, p95, p99) of ``repeats`` x 100 events (20 with
    ``quick``), FULL and NORMAL interleaved, and every fourth event acknowledged (FULL)."""
    from sqlalchemy import event

    from common.event_kinds import EventKind
    from server.records.history import HistoryStore, default_url
    from server.records.monitor_events import EventAction, MonitorEvent

    n = repeats * (20 if quick else 100)
    times: dict[str, list[float]] = {"full": [], "normal": [], "ack": []}
    with tempfile.TemporaryDirectory(prefix="cutwatch-bench-history-") as tmp:
        full = HistoryStore(default_url(Path(tmp) / "full"))
        normal = HistoryStore(default_url(Path(tmp) / "normal"))

        def _normal(dbapi_conn: Any, _record: Any) -> None:
            dbapi_conn.execute("PRAGMA synchronous=NORMAL")  # after the store's own pragmas

        event.listen(normal.engine, "connect", _normal)
        normal.engine.dispose()  # new connections get it
        for i in range(n):
            for name, st in (("full", full), ("normal", normal)):
                ev = MonitorEvent(EventKind.BREAKAGE, EventAction.FEED_HOLD, float(i), tool=1,
                                  value=3.0, limit=2.0, unit="", message="x" * 80)  # fmt: skip
                t0 = time.perf_counter()
                st.add_events([ev])
                times[name].append(time.perf_counter() - t0)
                if name == "full" and i % 4 == 0:
                    t0 = time.perf_counter()
                    st.acknowledge(ev.id, "operator")
                    times["ack"].append(time.perf_counter() - t0)
        with normal.engine.connect() as conn:
            sync = conn.exec_driver_sql("PRAGMA synchronous").scalar()
        assert sync == 1, f"synchronous: expected NORMAL (1) on the comparison store, got {sync}"
        full.close()
        normal.close()
    out: Figures = {"events": n, "directory": tempfile.gettempdir()}
    for name, xs in times.items():
        out.update(_stats(name, xs))
    out["full_over_normal_median"] = statistics.median(times["full"]) / statistics.median(
        times["normal"]
    )
    return out
