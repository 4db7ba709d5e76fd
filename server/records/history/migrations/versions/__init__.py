"""The history's migration scripts, oldest first (Alembic reads them by revision)."""
