"""The mebm database: SQLAlchemy 2.x models, Alembic migrations, repository functions.

Use: ``engine = make_engine(url); upgrade(engine); factory = make_session_factory(engine)``,
then ``with session_scope(factory) as s: config_repo.list_machines(s)``. Repository
functions take a session and core types and return core types or the frozen
records of :mod:`storage.db.records`.
"""

from storage.db import circles_repo, config_repo, leases, maintenance_repo, results_repo, ui_sessions_repo, webhooks_repo
from storage.db.engine import (
    integrity_problems,
    is_sqlite,
    make_engine,
    make_session_factory,
    ping,
    session_scope,
    sqlite_url,
)
from storage.db.errors import (
    ConflictError,
    DatabaseUnavailableError,
    NotFoundError,
    StorageError,
    WaitingCycleError,
)
from storage.db.migrate import current_revision, head_revision, upgrade
from storage.db.records import (
    AlertRecord,
    AxisRecord,
    AxisSettings,
    CircularTestRecord,
    CycleRecord,
    FinishedCycle,
    KeyRecord,
    MachineRecord,
    OrderRequest,
    RepairRecord,
    TransitionRecord,
    WorkOrderRecord,
    ResultRecord,
    Schedule,
    TbeRecord,
    TrendSeries,
    TrendView,
    as_utc,
    utcnow,
)

__all__ = [
    "AlertRecord", "AxisRecord", "CircularTestRecord", "circles_repo", "AxisSettings", "ConflictError", "CycleRecord", "DatabaseUnavailableError",
    "FinishedCycle", "KeyRecord", "MachineRecord", "NotFoundError", "ResultRecord", "Schedule", "StorageError",
    "TbeRecord", "TrendSeries", "TrendView", "as_utc", "config_repo", "current_revision", "head_revision", "integrity_problems",
    "is_sqlite", "leases", "maintenance_repo", "OrderRequest", "RepairRecord", "TransitionRecord", "WorkOrderRecord",
    "make_engine", "make_session_factory", "ping", "results_repo", "session_scope", "sqlite_url", "ui_sessions_repo",
    "upgrade", "utcnow", "WaitingCycleError", "webhooks_repo",
]
