"""Engine settings, migrations and the translation of connection failures."""

from __future__ import annotations

import pytest
from alembic.autogenerate import compare_metadata
from alembic.runtime.migration import MigrationContext
from sqlalchemy import text

from storage.db import (
    DatabaseUnavailableError,
    current_revision,
    head_revision,
    make_engine,
    make_session_factory,
    ping,
    session_scope,
    upgrade,
)
from storage.db.models import Base
from storage.db import config_repo


def test_migrations_match_the_models(engine):
    assert current_revision(engine) == head_revision()
    with engine.connect() as conn:
        diff = compare_metadata(MigrationContext.configure(conn), Base.metadata)
    assert diff == []


def test_upgrade_is_idempotent(engine):
    upgrade(engine)
    assert current_revision(engine) == head_revision()


def test_sqlite_runs_wal_with_foreign_keys(tmp_path):
    eng = make_engine(f"sqlite:///{tmp_path}/sub/db.sqlite3")
    with eng.connect() as c:
        assert c.execute(text("PRAGMA journal_mode")).scalar_one() == "wal"
        assert c.execute(text("PRAGMA foreign_keys")).scalar_one() == 1
    eng.dispose()


def test_unreachable_database_is_reported_as_unavailable():
    eng = make_engine("postgresql://nobody@127.0.0.1:1/none")
    with pytest.raises(DatabaseUnavailableError, match="unavailable"):
        ping(eng)
    with pytest.raises(DatabaseUnavailableError), session_scope(make_session_factory(eng)) as s:
        config_repo.list_machines(s)
