"""Machines and axes carry a uuid beyond their ids: set on creation, and given by the
migration to the rows stored before it. SQLite and PostgreSQL."""

from __future__ import annotations

import uuid
from datetime import datetime, timezone

import pytest
from sqlalchemy import exc as sa_exc
from sqlalchemy import inspect, text

from storage.db import config_repo, make_engine, make_session_factory, session_scope, upgrade
from tests.storage.db import factories as f
from tests.storage.db.backends import BACKENDS, make_database

def downgrade(engine, revision):
    from alembic import command

    from storage.db.migrate import alembic_config

    cfg = alembic_config()
    with engine.begin() as conn:
        cfg.attributes["connection"] = conn
        command.downgrade(cfg, revision)


NOW = datetime(2026, 3, 1, tzinfo=timezone.utc)


@pytest.mark.parametrize("backend", BACKENDS)
def test_the_migration_gives_every_stored_machine_and_axis_its_own_uuid(backend, tmp_path):
    url, handle = make_database(backend, tmp_path)
    engine = make_engine(url)
    try:
        upgrade(engine, "0010")
        with engine.begin() as c:  # as 0010 stored them: no uuid column yet
            for name in ("old-1", "old-2"):
                c.execute(text("INSERT INTO machines (name, description, created_at) VALUES (:n, '', :t)"),
                          {"n": name, "t": NOW})
            mids = c.execute(text("SELECT id FROM machines ORDER BY id")).scalars().all()
            for mid in mids:
                c.execute(text(
                    "INSERT INTO axes (machine_id, name, transmission_mm_per_rev, screw_lead_mm, position_gain_per_s, "
                    "travel_start_mm, travel_end_mm, controller_url, measure_feed_mm_min, measure_acceleration_mm_s2, "
                    "warning_fraction, decision_rule, schedule_enabled, in_service_since, created_at) VALUES "
                    "(:m, 'y', 6.857, 16.0, 10.0, 0.0, 500.0, 'sim', 2000.0, 500.0, 0.9, 'guarded', true, :t, :t)"),
                    {"m": mid, "t": NOW})
        upgrade(engine)
        with engine.connect() as c:
            machines = c.execute(text("SELECT uuid FROM machines")).scalars().all()
            axes = c.execute(text("SELECT uuid FROM axes")).scalars().all()
        ids = machines + axes
        assert len(ids) == 4 and len(set(ids)) == 4
        assert all(str(uuid.UUID(u)) == u for u in ids)
        with session_scope(make_session_factory(engine)) as s:  # the records carry them
            recs = config_repo.list_axes(s)
        assert sorted(r.uuid for r in recs) == sorted(axes) and sorted(r.machine_uuid for r in recs) == sorted(machines)
        with pytest.raises(sa_exc.IntegrityError), engine.begin() as c:  # unique
            c.execute(text("UPDATE axes SET uuid = :u"), {"u": axes[0]})
        downgrade(engine, "0010")  # and back: the rows that refer to the machines and axes stay
        with engine.connect() as c:
            assert c.execute(text("SELECT count(*) FROM axes")).scalar_one() == 2
            assert "uuid" not in {col["name"] for col in inspect(c).get_columns("machines")}
        upgrade(engine)
        with engine.connect() as c:
            again = c.execute(text("SELECT uuid FROM axes")).scalars().all()
        assert len(set(again)) == 2 and None not in again
    finally:
        engine.dispose()
        if handle is not None:
            handle.drop()


def test_created_machines_and_axes_get_a_fresh_uuid(engine):
    factory = make_session_factory(engine)
    with session_scope(factory) as s:
        m1 = config_repo.create_machine(s, "m1")
        m2 = config_repo.create_machine(s, "m2")
        a1 = config_repo.create_axis(s, m1.id, f.settings())
        a2 = config_repo.create_axis(s, m2.id, f.settings())
        again = config_repo.get_axis(s, a1.id)
    assert len({m1.uuid, m2.uuid, a1.uuid, a2.uuid}) == 4 and all(len(u) == 36 for u in (m1.uuid, a1.uuid))
    assert (again.uuid, again.machine_uuid) == (a1.uuid, m1.uuid) and a2.machine_uuid == m2.uuid
