"""Storage errors: one subtree of :class:`core.errors.MebmError`.

SQLAlchemy and driver exceptions are translated here (``raise ... from``) so callers
never see a foreign exception; only ``api/`` maps these to HTTP codes.
"""

from __future__ import annotations

from core.errors import InputError, MebmError


class StorageError(MebmError):
    """Something went wrong in the database layer."""


class DatabaseUnavailableError(StorageError, ConnectionError):
    """The database cannot be reached (server down, file locked, disk gone)."""


class NotFoundError(StorageError, LookupError):
    """An id that does not exist. ``kind`` names the entity (``axis``, ``measurement``)."""

    def __init__(self, kind: str, ident):
        self.kind = kind
        self.ident = ident
        super().__init__(f"no {kind} with id {ident!r}")


class ConflictError(StorageError, InputError):
    """The request contradicts what is stored (duplicate name, state that forbids it)."""


class WaitingCycleError(ConflictError):
    """A manual measurement of the axis is waiting already (at most one may wait).
    ``cycle`` is the waiting one when known; ``retry_after_s`` when to ask again."""

    def __init__(self, axis_id: int, cycle=None, retry_after_s: float = 30.0):
        self.axis_id = axis_id
        self.cycle = cycle
        self.retry_after_s = retry_after_s
        which = f" (measurement {cycle.id})" if getattr(cycle, "id", None) else ""
        super().__init__(f"axis {axis_id} has a manual measurement waiting already{which}: "
                         "at most one may wait; ask again once it has started")
