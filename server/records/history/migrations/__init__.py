"""Alembic's migration environment of the history (``env.py``) and its scripts
(``versions/``), inside the package so an installed service migrates its own database
at start (:func:`server.records.history.store.migrate`)."""
