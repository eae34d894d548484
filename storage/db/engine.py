"""Engines and sessions. Nothing is connected at import time.

SQLite (the default) runs in WAL mode with foreign keys on and a busy timeout, so the
API can read while a cycle writes, and ``synchronous=FULL``, so a commit survives a power
cut once it has returned. PostgreSQL is used as is. :func:`session_scope`
commits or rolls back one unit of work and translates connection failures into
:class:`DatabaseUnavailableError`.
"""

from __future__ import annotations

import contextlib
from collections.abc import Iterator
from pathlib import Path

from sqlalchemy import Engine, create_engine, event, text
from sqlalchemy import exc as sa_exc
from sqlalchemy.orm import Session, sessionmaker

from storage.db.errors import DatabaseUnavailableError, StorageError

SQLITE_FILE = "mebm.sqlite3"


def sqlite_url(data_dir: str | Path) -> str:
    """URL of the default SQLite database file inside ``data_dir``."""
    return f"sqlite:///{Path(data_dir).resolve() / SQLITE_FILE}"


def is_sqlite(url_or_engine) -> bool:
    url = url_or_engine.url if isinstance(url_or_engine, Engine) else str(url_or_engine)
    return str(url).startswith("sqlite")


def make_engine(url: str, *, echo: bool = False, idle_in_transaction_timeout_s: float | None = None) -> Engine:
    """An engine for ``url``. SQLite: WAL, synchronous=FULL, foreign keys, 10 s busy timeout; the parent
    folder of the file is created. PostgreSQL: pre-ping so a restarted server is noticed."""
    if is_sqlite(url):
        path = url.split("///", 1)[-1]
        if path and path != ":memory:":
            Path(path).parent.mkdir(parents=True, exist_ok=True)
        engine = create_engine(
            url, echo=echo, connect_args={"check_same_thread": False, "timeout": 10.0},
            pool_size=10, max_overflow=20,
        )

        @event.listens_for(engine, "connect")
        def _pragmas(dbapi_conn, _record):  # pragma: no cover - exercised by every test
            cur = dbapi_conn.cursor()
            cur.execute("PRAGMA journal_mode=WAL")
            cur.execute("PRAGMA foreign_keys=ON")
            # FULL: a commit is on disk when it returns (NORMAL, in WAL mode, may lose the last
            # commits on a power cut), so the cycle's spool file may be deleted right after it
            cur.execute("PRAGMA synchronous=FULL")
            cur.execute("PRAGMA busy_timeout=10000")
            cur.close()

        return engine
    if url.startswith("postgresql://"):
        url = "postgresql+psycopg://" + url[len("postgresql://"):]
    connect_args: dict = {"connect_timeout": 5}
    if idle_in_transaction_timeout_s is not None:
        # a fleet worker cut from the server mid-transaction must not keep its row locks (its
        # lease rows) until TCP gives up: the server ends such a session after this long
        ms = int(idle_in_transaction_timeout_s * 1000)
        connect_args["options"] = f"-c idle_in_transaction_session_timeout={ms}"
    return create_engine(
        url, echo=echo, pool_pre_ping=True, pool_size=10, max_overflow=20, connect_args=connect_args,
    )


def make_session_factory(engine: Engine) -> sessionmaker[Session]:
    return sessionmaker(engine, expire_on_commit=False)


def translate(exc: Exception) -> StorageError:
    """A SQLAlchemy exception as a storage error (for ``raise translate(e) from e``)."""
    if isinstance(exc, (sa_exc.OperationalError, sa_exc.InterfaceError)) or (
        isinstance(exc, sa_exc.DBAPIError) and exc.connection_invalidated
    ):
        return DatabaseUnavailableError(f"database unavailable: {str(exc.orig if hasattr(exc, 'orig') else exc).strip()}")
    return StorageError(f"database error: {type(exc).__name__}: {exc}")


@contextlib.contextmanager
def session_scope(factory: sessionmaker[Session]) -> Iterator[Session]:
    """One unit of work: commit on success, roll back on any error. Without a factory (a
    service whose database is not open yet) :class:`DatabaseUnavailableError`."""
    if factory is None:
        raise DatabaseUnavailableError("database unavailable: not open yet")
    session = factory()
    try:
        yield session
        session.commit()
    except sa_exc.SQLAlchemyError as exc:
        with contextlib.suppress(Exception):
            session.rollback()
        raise translate(exc) from exc
    except BaseException:
        with contextlib.suppress(Exception):
            session.rollback()
        raise
    finally:
        with contextlib.suppress(Exception):
            session.close()


def ping(engine: Engine) -> None:
    """Raise :class:`DatabaseUnavailableError` unless a trivial query answers."""
    try:
        with engine.connect() as conn:
            conn.execute(text("SELECT 1"))
    except sa_exc.SQLAlchemyError as exc:
        raise translate(exc) from exc


def integrity_problems(engine: Engine) -> list[str]:
    """Integrity check: SQLite ``integrity_check`` + ``foreign_key_check``; on every
    backend, no orphan rows and no result without its cycle. Empty list = healthy."""
    problems: list[str] = []
    with engine.connect() as conn:
        if is_sqlite(engine):
            rows = [r[0] for r in conn.execute(text("PRAGMA integrity_check"))]
            if rows != ["ok"]:
                problems += [f"integrity_check: {r}" for r in rows]
            problems += [f"foreign_key_check: {tuple(r)}" for r in conn.execute(text("PRAGMA foreign_key_check"))]
        orphan = conn.execute(text(
            "SELECT count(*) FROM results r LEFT JOIN cycles c ON c.id = r.cycle_id WHERE c.id IS NULL"
        )).scalar_one()
        if orphan:
            problems.append(f"{orphan} result(s) without a cycle")
        mismatch = conn.execute(text(
            "SELECT count(*) FROM results r JOIN cycles c ON c.id = r.cycle_id WHERE c.status <> 'ok'"
        )).scalar_one()
        if mismatch:
            problems.append(f"{mismatch} result(s) whose cycle is not 'ok'")
    return problems
