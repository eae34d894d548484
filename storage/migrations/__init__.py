"""Alembic migrations of the mebm database (run by ``storage.db.migrate.upgrade``)."""
