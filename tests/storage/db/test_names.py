"""Names that meet on the interfaces (storage.db.names): refused even when two
creations run at once on PostgreSQL, where each transaction sees only committed rows."""

from __future__ import annotations

import threading

import pytest
from sqlalchemy import text

from storage.db import ConflictError, config_repo, make_session_factory, session_scope
from storage.db.names import collision, interface_name
from tests.waiting import until


def test_interface_names_and_their_collisions():
    assert [interface_name(n) for n in ("m a", "m_a", "m/a", "m  a", "m a_", " m+#a ", "m-a", "__")] == \
        ["m_a", "m_a", "m_a", "m_a", "m_a", "m_a", "m-a", "_"]
    assert collision("m_a", ["x", "m a"]) == "m a"
    assert collision("m a", ["m a", "m-a"]) is None  # itself is not a collision


def test_two_creations_that_meet_on_mqtt_at_once_leave_one(engine):
    if engine.dialect.name != "postgresql":
        pytest.skip("SQLite takes one writer at a time by itself")
    factory = make_session_factory(engine)
    first = factory()
    config_repo.create_machine(first, "m a")  # not committed yet
    outcome = {}

    def second():
        try:
            with session_scope(factory) as s:
                config_repo.create_machine(s, "m_a")
            outcome["created"] = True
        except ConflictError as exc:
            outcome["refused"] = str(exc)

    t = threading.Thread(target=second)
    t.start()
    with engine.connect() as c:  # the second waits for the first's check to be committed
        until(lambda: c.execute(text("SELECT count(*) FROM pg_locks WHERE locktype = 'advisory' AND NOT granted"))
              .scalar_one() > 0 or not t.is_alive(), "the second creation at the lock")
    first.commit()
    first.close()
    t.join(30)
    assert "'m a'" in outcome.get("refused", ""), outcome
    with session_scope(factory) as s:
        assert [m.name for m in config_repo.list_machines(s)] == ["m a"]
