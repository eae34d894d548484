"""Database backends for the storage and API suites: SQLite and PostgreSQL.

PostgreSQL: a uniquely named database is created from ``test`` on 127.0.0.1:5432
(trust auth; user from MEBM_TEST_PG_USER, else postgres, else root) for the test
session and dropped afterwards. When no server answers, the PostgreSQL run is skipped
with a message saying so, except under ``CI=true``, where it fails: CI must run them.
MEBM_TEST_PG_URL overrides the server URL.
"""

from __future__ import annotations

import os
import uuid

import pytest
from sqlalchemy import create_engine, text

from storage.db import make_engine, upgrade
from storage.db.models import Base

PG_SERVER = os.environ.get("MEBM_TEST_PG_URL", "postgresql+psycopg://{user}@127.0.0.1:5432/test")
BACKENDS = ("sqlite", "postgresql")
_skip_reason: str | None = None


def _admin_engine():
    last = None
    for user in filter(None, (os.environ.get("MEBM_TEST_PG_USER"), "postgres", "root")):
        url = PG_SERVER.format(user=user)
        eng = create_engine(url, isolation_level="AUTOCOMMIT", connect_args={"connect_timeout": 3})
        try:
            with eng.connect() as c:
                c.execute(text("SELECT 1"))
            return eng, url
        except Exception as exc:  # noqa: BLE001 - any failure means: no usable server
            last = exc
            eng.dispose()
    raise RuntimeError(str(last).splitlines()[0] if last else "no user")


class PgDatabase:
    """A throw-away PostgreSQL database; ``url`` for the product's engine."""

    def __init__(self):
        self.admin, server_url = _admin_engine()
        self.name = f"mebm_test_{uuid.uuid4().hex[:12]}"
        with self.admin.connect() as c:
            c.execute(text(f'CREATE DATABASE "{self.name}"'))
        self.url = server_url.rsplit("/", 1)[0] + "/" + self.name

    def drop(self) -> None:
        with self.admin.connect() as c:
            c.execute(text(f'DROP DATABASE IF EXISTS "{self.name}" WITH (FORCE)'))
        self.admin.dispose()


def _in_ci() -> bool:
    return os.environ.get("CI", "").strip().lower() in ("1", "true", "yes")


def make_database(backend: str, tmp_dir) -> tuple[str, object]:
    """(url, handle) of a fresh empty database; ``handle.drop()`` removes a PG one."""
    global _skip_reason
    if backend == "sqlite":
        return f"sqlite:///{tmp_dir}/mebm.sqlite3", None
    if _skip_reason is not None:
        pytest.skip(_skip_reason)
    try:
        db = PgDatabase()
    except Exception as exc:  # noqa: BLE001
        where = PG_SERVER.split("@", 1)[-1]
        if _in_ci():
            pytest.fail(f"CI=true and no PostgreSQL server reachable at {where} ({exc}): CI runs the "
                        "PostgreSQL tests, it does not skip them (.ci/run says how the server is reached)",
                        pytrace=False)
        _skip_reason = f"PostgreSQL run skipped: no server reachable at {where} ({exc})"
        pytest.skip(_skip_reason)
    return db.url, db


BIG_TABLE_ROWS = 1000  # beyond this, TRUNCATE (one new file) is cheaper than DELETE (row by row)


def truncate_all(engine) -> None:
    """Every table emptied; on PostgreSQL the ids start at 1 again.

    PostgreSQL: TRUNCATE for a table holding many rows only; a table holding a few is
    DELETEd from, since TRUNCATE gives every table and index it names a new file and waits
    for the disk (a third of a second per test for all the tables on a busy host, against a
    few milliseconds to delete the few rows most tests leave)."""
    tables = Base.metadata.sorted_tables
    with engine.begin() as c:
        if engine.dialect.name != "postgresql":
            for t in reversed(tables):
                c.execute(t.delete())
            return
        counts = c.execute(text(" UNION ALL ".join(
            f"SELECT '{t.name}', (SELECT count(*) FROM (SELECT 1 FROM \"{t.name}\" LIMIT {BIG_TABLE_ROWS + 1}) AS r)"
            for t in tables))).all()
        rows = dict(counts)
        big = [t.name for t in tables if rows[t.name] > BIG_TABLE_ROWS]
        if big:  # (CASCADE: the tables referring to them too)
            names = ", ".join(f'"{n}"' for n in big)
            c.execute(text(f"TRUNCATE {names} RESTART IDENTITY CASCADE"))
        for t in reversed(tables):  # children first
            if rows[t.name] and t.name not in big:
                c.execute(t.delete())
        sequences = c.execute(text("SELECT quote_ident(sequence_schema) || '.' || quote_ident(sequence_name) "
                                   "FROM information_schema.sequences")).scalars().all()
        for name in sequences:
            c.execute(text(f"ALTER SEQUENCE {name} RESTART"))


@pytest.fixture(scope="session", params=BACKENDS)
def db_url(request, tmp_path_factory):
    """A migrated database per backend for the whole session."""
    url, handle = make_database(request.param, tmp_path_factory.mktemp(request.param))
    eng = make_engine(url)
    upgrade(eng)
    eng.dispose()
    yield url
    if handle is not None:
        handle.drop()


@pytest.fixture
def engine(db_url):
    eng = make_engine(db_url)
    truncate_all(eng)
    yield eng
    eng.dispose()
