"""The history store: events, acknowledgements and tool lives in one database.

:class:`HistoryStore` writes and queries the tables of
:mod:`server.records.history.tables` through SQLAlchemy; the database is migrated to the
newest schema when the store opens (:func:`migrate`: Alembic's ``upgrade head`` with the
scripts of this package, so an installed service migrates itself). The default database
is SQLite, ``data_dir/history/cutwatch.sqlite``; ``CUTWATCH_HISTORY_URL`` names another
(any SQLAlchemy URL, e.g. ``postgresql+psycopg://...``).

Durability: every write is one transaction, committed before the call returns, so what a
caller was told is stored (an acknowledgement answered, an event handed over) survives a
SIGKILL of the service. SQLite runs in WAL mode with ``synchronous=FULL``: a commit
returns only after the write-ahead log is on the disk (fsync), so a committed row also
survives a power cut or an OS crash, not only a killed process (``NORMAL`` would keep the
last commits in the page cache). The events are few (a handful per hour), so the fsync per
write costs nothing that matters (docs/monitoring.md has the measured cost); the writes
are made on the caller's thread, with no queue whose content a kill could lose.
"""

from __future__ import annotations

import math
import threading
import time
from collections.abc import Iterable, Mapping, Sequence
from pathlib import Path
from typing import Any, NotRequired, TypedDict

from alembic import command
from alembic.config import Config
from alembic.runtime.migration import MigrationContext
from alembic.script import ScriptDirectory
from sqlalchemy import Engine, create_engine, event, func, select
from sqlalchemy.engine import Connection
from sqlalchemy.exc import IntegrityError
from sqlalchemy.sql import Select

from common.event_kinds import EventKind
from server.records.history.tables import acknowledgements, events, tool_life
from server.records.monitor_events import KINDS, EventFields, EventRecord, MonitorEvent

#: where the history lies in the service's data directory
RELATIVE_PATH = Path("history") / "cutwatch.sqlite"
#: the migration scripts (Alembic's script location)
MIGRATIONS = Path(__file__).resolve().parent / "migrations"
#: why a tool left the spindle
CAUSES: tuple[str, ...] = (
    EventKind.WEAR_LIMIT,
    EventKind.BREAKAGE,
    EventKind.MISSING_TOOL,
    EventKind.COLLISION,
    "manual",
    "unknown",
)
#: the most rows one query gives
MAX_LIMIT = 1000


def sqlite_url(path: Path) -> str:
    """The SQLAlchemy URL of the SQLite file ``path``."""
    return f"sqlite:///{Path(path).resolve()}"


def default_url(data_dir: Path) -> str:
    """The history of a data directory: ``data_dir/history/cutwatch.sqlite``."""
    return sqlite_url(Path(data_dir) / RELATIVE_PATH)


def alembic_config(url: str, conn: Connection | None = None) -> Config:
    """Alembic's configuration, built in code (no ``alembic.ini``): the scripts of this
    package, the database ``url``, and the connection to migrate on, when given."""
    cfg = Config()
    cfg.set_main_option("script_location", str(MIGRATIONS))
    cfg.set_main_option("sqlalchemy.url", url.replace("%", "%%"))
    if conn is not None:
        cfg.attributes["connection"] = conn
    return cfg


def head_revision() -> str | None:
    """The newest migration's revision."""
    return ScriptDirectory.from_config(alembic_config("sqlite://")).get_current_head()


def current_revision(engine: Engine) -> str | None:
    """The revision the database is at (None: not migrated yet)."""
    with engine.connect() as conn:
        return MigrationContext.configure(conn).get_current_revision()


def migrate(engine: Engine) -> None:
    """Bring the database to the newest schema (nothing to do when it is there already)."""
    with engine.begin() as conn:
        command.upgrade(alembic_config(str(engine.url), conn), "head")


def _sqlite_pragmas(dbapi_conn: Any, _record: Any) -> None:
    cur = dbapi_conn.cursor()
    cur.execute("PRAGMA journal_mode=WAL")  # readers never wait for the writer
    cur.execute("PRAGMA synchronous=FULL")  # fsync the log at every commit (docstring)
    cur.execute("PRAGMA foreign_keys=ON")
    cur.execute("PRAGMA busy_timeout=5000")
    cur.close()


def open_engine(url: str) -> Engine:
    """An engine on ``url``; a SQLite file's directory is made and its pragmas set."""
    if url.startswith("sqlite"):
        db = url.split("///", 1)[1] if "///" in url else ""
        if db and db != ":memory:":
            Path(db).parent.mkdir(parents=True, exist_ok=True)
        engine = create_engine(url)
        event.listen(engine, "connect", _sqlite_pragmas)
        return engine
    return create_engine(url, pool_pre_ping=True)


def _num(x: object) -> float | None:
    """A float for the database: NaN and None are NULL."""
    if x is None:
        return None
    v = float(x)  # type: ignore[arg-type]
    return v if math.isfinite(v) else None


class EventRow(EventRecord):
    """An event as the history gives it: its record with the time it was received."""

    received_wall: float


class _EventInsert(EventFields):
    """An event's row as written (its acknowledgement is a row of its own)."""

    received_wall: float


class ToolChange(TypedDict):
    """A tool taken out of the spindle, as a part ends its life
    (:meth:`server.pipeline.part.Part.take_tool_changes`) and :meth:`HistoryStore.add_tool_changes`
    records it: times on the source's clock [s], wear [mm] (None: not known)."""

    tool: int
    index: int | None
    start_t: float
    end_t: float
    wear_at_change_mm: float | None
    cause: str
    wear_true_mm: NotRequired[float | None]
    wear_true_share: NotRequired[float | None]
    start_wall: NotRequired[float | None]
    end_wall: NotRequired[float | None]
    machine: NotRequired[str]


class ToolLifeRow(TypedDict):
    """A tool life as the history keeps and gives it (``GET /api/tool-life``'s item)."""

    machine: str
    tool: int
    start_t: float | None
    end_t: float
    start_wall: float | None
    end_wall: float
    wear_at_change_mm: float | None
    wear_true_mm: float | None
    wear_true_share: float | None
    cause: str
    index: int | None
    wear_measured_mm: float | None


class _ToolLifeInsert(TypedDict):
    """A tool life's row as written (the table's columns but ``seq``)."""

    machine: str
    tool: int
    tool_index: int | None
    start_t: float | None
    end_t: float
    start_wall: float | None
    end_wall: float
    wear_at_change_mm: float | None
    wear_true_mm: float | None
    wear_true_share: float | None
    cause: str


def _event_row(r: Mapping[Any, Any]) -> EventRow:
    """An event as the stream and REST carry it (``Event``) with its received time."""
    return {
        "id": r["id"],
        "kind": r["kind"],
        "action": r["action"],
        "t": r["t"],
        "tool": r["tool"],
        "program": r["program"],
        "line": r["line"],
        "part": r["part"],
        "value": r["value"],
        "limit": r["limit"],
        "unit": r["unit"],
        "message": r["message"],
        "machine": r["machine"],
        "acked": r["by"] is not None,
        "acked_by": r["by"],
        "acked_wall": r["ack_wall"],
        "received_wall": r["received_wall"],
    }


def _life_row(r: Mapping[Any, Any]) -> ToolLifeRow:
    """A row of ``tool_life`` (its ``tool_index`` named ``index``, last; no ``seq``)."""
    return {
        "machine": r["machine"],
        "tool": r["tool"],
        "start_t": r["start_t"],
        "end_t": r["end_t"],
        "start_wall": r["start_wall"],
        "end_wall": r["end_wall"],
        "wear_at_change_mm": r["wear_at_change_mm"],
        "wear_true_mm": r["wear_true_mm"],
        "wear_true_share": r["wear_true_share"],
        "cause": r["cause"],
        "index": r["tool_index"],
        "wear_measured_mm": r.get("wear_measured_mm"),
    }


class HistoryStore:
    """The kept history (module docstring). Thread-safe: writes are serialised.

    Parameters
    ----------
    url
        A SQLAlchemy database URL (:func:`default_url` for a data directory).
    machine
        The machine's name, stamped on events and tool lives that carry none.
    """

    def __init__(self, url: str, *, machine: str = "") -> None:
        self.url = url
        self.machine = machine
        self.engine = open_engine(url)
        migrate(self.engine)
        self._write = threading.Lock()
        #: writes committed, and their total wall time [s] (the cost per write)
        self.writes = 0
        self.write_s = 0.0

    @classmethod
    def for_data_dir(
        cls, data_dir: Path | None, url: str | None = None, *, machine: str = ""
    ) -> HistoryStore | None:
        """The history of a service: ``url`` if given, else the data directory's SQLite
        file; None when there is neither."""
        if url:
            return cls(url, machine=machine)
        if data_dir is None:
            return None
        return cls(default_url(data_dir), machine=machine)

    def close(self) -> None:
        self.engine.dispose()

    def _timed(self, t0: float) -> None:
        self.writes += 1
        self.write_s += time.perf_counter() - t0

    # ------------------------------------------------------------------ events
    def add_events(self, evs: Iterable[MonitorEvent], wall: float | None = None) -> None:
        """Store ``evs`` (received at ``wall``, default now) in one transaction, committed
        before the call returns; an event whose id is stored already is skipped."""
        rows: list[_EventInsert] = []
        now = time.time() if wall is None else wall
        for ev in evs:
            d = ev.as_dict()
            row: _EventInsert = {**d, "received_wall": now}
            row["machine"] = d["machine"] or self.machine
            row["value"], row["limit"] = _num(d["value"]), _num(d["limit"])
            rows.append(row)
        if not rows:
            return
        t0 = time.perf_counter()
        with self._write, self.engine.begin() as conn:
            ids = [r["id"] for r in rows]
            have = set(conn.scalars(select(events.c.id).where(events.c.id.in_(ids))))
            new = [r for r in rows if r["id"] not in have]
            if new:
                conn.execute(events.insert(), new)
        self._timed(t0)

    def _query(self) -> Select[Any]:
        a = acknowledgements
        return select(*events.c, a.c.by, a.c.wall.label("ack_wall")).outerjoin(
            a, a.c.event_id == events.c.id
        )

    def event(self, event_id: str) -> EventRow | None:
        """One event with its acknowledgement (None: no such event)."""
        with self.engine.connect() as conn:
            r = conn.execute(self._query().where(events.c.id == event_id)).mappings().first()
        return None if r is None else _event_row(r)

    def acknowledged(self, event_id: str, by: str, wall: float | None = None) -> EventRow | None:
        """Acknowledge an event (committed before the call returns); acknowledging it
        again changes nothing and gives the first acknowledgement. The event with its
        acknowledgement; None when there is no such event."""
        t0 = time.perf_counter()
        with self._write:
            if self.event(event_id) is None:
                return None
            try:
                with self.engine.begin() as conn:
                    conn.execute(
                        acknowledgements.insert().values(
                            event_id=event_id, by=by, wall=time.time() if wall is None else wall
                        )
                    )
            except IntegrityError:  # acknowledged already (by another process, too)
                pass
            else:
                self._timed(t0)
        return self.event(event_id)

    def acknowledge(self, event_id: str, by: str, wall: float | None = None) -> EventRow | None:
        """:meth:`acknowledged` (what the runtime's ``EventHistory`` protocol asks,
        ``server/pipeline/runtime.py``)."""
        ev = self.acknowledged(event_id, by, wall)
        return None if ev is None else ev.copy()

    def events(
        self,
        *,
        kind: str | None = None,
        tool: int | None = None,
        acked: bool | None = None,
        since: float | None = None,
        until: float | None = None,
        limit: int = 100,
        offset: int = 0,
    ) -> tuple[int, list[EventRow]]:
        """Events newest first (by received time), filtered: ``kind`` (one of
        :data:`~server.records.monitor_events.KINDS`), ``tool``, ``acked``, received at
        or after ``since`` and before ``until`` (Unix s); a page of ``limit`` from
        ``offset``. The number matching and the page."""
        if kind is not None and kind not in KINDS:
            raise ValueError(f"kind: expected one of {', '.join(KINDS)}, got {kind!r}")
        q = self._query()
        conds = []
        if kind is not None:
            conds.append(events.c.kind == kind)
        if tool is not None:
            conds.append(events.c.tool == tool)
        if acked is not None:
            ack = acknowledgements.c.event_id
            conds.append(ack.is_not(None) if acked else ack.is_(None))
        if since is not None:
            conds.append(events.c.received_wall >= since)
        if until is not None:
            conds.append(events.c.received_wall < until)
        q = q.where(*conds)
        page = q.order_by(events.c.received_wall.desc(), events.c.seq.desc())
        page = page.limit(min(limit, MAX_LIMIT)).offset(offset)
        count = select(func.count()).select_from(q.subquery())
        with self.engine.connect() as conn:
            total = int(conn.scalar(count) or 0)
            rows = conn.execute(page).mappings().all()
        return total, [_event_row(r) for r in rows]

    def recent(self, n: int, *, unacked: bool = False) -> list[EventRow]:
        """The latest ``n`` events (only those not acknowledged: ``unacked``), oldest first:
        what a restarted service shows again (what the runtime's ``EventHistory`` asks)."""
        _, items = self.events(acked=False if unacked else None, limit=n)
        return items[::-1]

    # ------------------------------------------------------------------ tool lives
    def add_tool_changes(
        self, changes: Sequence[ToolChange], wall: float | None = None
    ) -> list[ToolLifeRow]:
        """Record tools taken out of the spindle (:meth:`LivePipeline.take_tool_changes`:
        ``tool``, ``index``, ``start_t``, ``end_t``, ``wear_at_change_mm``, ``cause``,
        optionally ``wear_true_mm``, ``wear_true_share``, ``start_wall``, ``end_wall``,
        ``machine``), committed
        before the call returns. ``end_wall`` defaults to ``wall`` (now); ``start_wall`` to
        the ``end_wall`` of the machine's previous record when that ended at this one's
        ``start_t`` (the tool mounted then), else NULL. The records as stored."""
        if not changes:
            return []
        now = time.time() if wall is None else wall
        t0 = time.perf_counter()
        out = []
        with self._write, self.engine.begin() as conn:
            for c in changes:
                cause = str(c.get("cause", "unknown"))
                if cause not in CAUSES:
                    raise ValueError(f"cause: expected one of {', '.join(CAUSES)}, got {cause!r}")
                machine = str(c.get("machine") or self.machine)
                start_t = _num(c.get("start_t"))
                row: _ToolLifeInsert = {
                    "machine": machine,
                    "tool": int(c["tool"]),
                    "tool_index": None if (index := c.get("index")) is None else int(index),
                    "start_t": start_t,
                    "end_t": float(c["end_t"]),
                    "start_wall": _num(c.get("start_wall")),
                    "end_wall": _num(c.get("end_wall")) or now,
                    "wear_at_change_mm": _num(c.get("wear_at_change_mm")),
                    "wear_true_mm": _num(c.get("wear_true_mm")),
                    "wear_true_share": _num(c.get("wear_true_share")),
                    "cause": cause,
                }
                if row["start_wall"] is None and start_t is not None:
                    row["start_wall"] = self._mounted_wall(conn, machine, start_t)
                conn.execute(tool_life.insert().values(**row))
                out.append(_life_row({"seq": 0, **row}))
        self._timed(t0)
        return out

    @staticmethod
    def _mounted_wall(conn: Connection, machine: str, start_t: float) -> float | None:
        prev = conn.execute(
            select(tool_life.c.end_t, tool_life.c.end_wall)
            .where(tool_life.c.machine == machine)
            .order_by(tool_life.c.seq.desc())
            .limit(1)
        ).first()
        if prev is not None and abs(prev.end_t - start_t) < 1e-6:
            return float(prev.end_wall)
        return None

    def measure_tool_life(
        self, tool: int, index: int, vb_mm: float, machine: str | None = None
    ) -> ToolLifeRow | None:
        """Enter the flank wear measured [mm] at the change of ``tool``'s life ``index``
        on ``machine`` (default this store's): its latest such record, committed before
        the call returns. The record as stored, None when there is none."""
        m = machine or self.machine
        t0 = time.perf_counter()
        with self._write, self.engine.begin() as conn:
            seq = conn.scalar(
                select(tool_life.c.seq)
                .where(tool_life.c.machine == m, tool_life.c.tool == int(tool),
                       tool_life.c.tool_index == int(index))
                .order_by(tool_life.c.seq.desc())
                .limit(1)
            )  # fmt: skip
            if seq is None:
                return None
            conn.execute(
                tool_life.update()
                .where(tool_life.c.seq == seq)
                .values(wear_measured_mm=float(vb_mm))
            )
            row = conn.execute(select(tool_life).where(tool_life.c.seq == seq)).mappings().one()
        self._timed(t0)
        return _life_row(row)

    def tool_life(
        self, *, tool: int | None = None, limit: int = 100, offset: int = 0
    ) -> tuple[int, list[ToolLifeRow]]:
        """Tool lives newest first (``tool``: of that tool number only); a page of
        ``limit`` from ``offset``. The number matching and the page."""
        q = select(tool_life)
        if tool is not None:
            q = q.where(tool_life.c.tool == tool)
        page = q.order_by(tool_life.c.seq.desc()).limit(min(limit, MAX_LIMIT)).offset(offset)
        with self.engine.connect() as conn:
            total = int(conn.scalar(select(func.count()).select_from(q.subquery())) or 0)
            rows = conn.execute(page).mappings().all()
        return total, [_life_row(r) for r in rows]

    def cost_per_write_ms(self) -> float:
        """The mean wall time of a committed write so far [ms] (NaN: none yet)."""
        return 1e3 * self.write_s / self.writes if self.writes else math.nan
