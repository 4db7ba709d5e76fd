"""The kept history of the process monitor: events, acknowledgements, tool lives.

:mod:`~server.records.history.store` (the store, migrated at open),
:mod:`~server.records.history.tables` (the tables) and the Alembic scripts in
``migrations/``.
"""

from server.records.history.store import CAUSES, HistoryStore, default_url, migrate

__all__ = ["CAUSES", "HistoryStore", "default_url", "migrate"]
