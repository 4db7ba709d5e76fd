"""Alembic's environment of the history: runs the migrations on the connection the caller
hands over (``config.attributes["connection"]``, as
:func:`server.records.history.store.migrate` does), or on ``sqlalchemy.url`` of the
configuration (the ``alembic`` command line)."""

from __future__ import annotations

from alembic import context
from sqlalchemy import create_engine
from sqlalchemy.engine import Connection

from server.records.history.tables import metadata


def run() -> None:
    config = context.config
    conn = config.attributes.get("connection")
    if conn is None:
        url = config.get_main_option("sqlalchemy.url")
        if not url:
            raise RuntimeError("sqlalchemy.url: expected a database URL, found none")
        engine = create_engine(url)
        with engine.connect() as own:
            _migrate(own)
        engine.dispose()
        return
    _migrate(conn)


def _migrate(conn: Connection) -> None:
    # render_as_batch: SQLite alters a table by copying it; Alembic's batch mode does that
    context.configure(connection=conn, target_metadata=metadata, render_as_batch=True)
    with context.begin_transaction():
        context.run_migrations()


run()
