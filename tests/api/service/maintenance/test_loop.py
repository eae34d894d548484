"""When the service opens an order: ALARM always (corrective); WARNING only
when the prognosis dates the backlash limit within the configured horizon
(condition-based, with the date as the order's due date); never a second one."""

from __future__ import annotations

from dataclasses import replace
from datetime import datetime, timedelta, timezone
from types import SimpleNamespace

import pytest

from api.service.config.settings import MaintenanceSettings
from api.service.events import EventHub
from api.service.maintenance.loop import MaintenanceLoop, next_verify_time
from api.service.status import compute_status
from storage.db import config_repo, maintenance_repo, make_session_factory, results_repo, session_scope
from tests.storage.db import factories as f
from tests.storage.db.backends import db_url, engine  # noqa: F401 - fixtures

DAY = 86400.0


class FixedStatus:
    """The status cache, with the prognosis' date set by the test."""

    def __init__(self, factory, limit_date_in_days):
        self.factory, self.days = factory, limit_date_in_days

    def get(self, axis_id):
        with session_scope(self.factory) as s:
            st = compute_status(s, axis_id)
        now = datetime.now(timezone.utc).timestamp()
        date = None if self.days is None else now + self.days * DAY
        return replace(st, history=SimpleNamespace(prognosis=SimpleNamespace(limit_date_s=date, now_s=now)))

    def invalidate(self, axis_id=None):
        pass


@pytest.fixture
def env(engine):  # noqa: F811
    factory = make_session_factory(engine)
    with session_scope(factory) as s:
        m = config_repo.create_machine(s, "vmc-850")
        axis_id = config_repo.create_axis(s, m.id, f.settings()).id
    return factory, axis_id


def _loop(factory, days, horizon=30.0):
    svc = SimpleNamespace(factory=factory, status=FixedStatus(factory, days), events=EventHub(), executor=None,
                          scheduler=None, simulators={})
    return MaintenanceLoop(svc, MaintenanceSettings(horizon_days=horizon))


def _store(factory, axis_id, b):
    with session_scope(factory) as s:
        cycle, alerts = results_repo.save_finished_cycle(s, f.finished(axis_id, b))
    return cycle, alerts


@pytest.mark.parametrize("days,opens", [(10.0, True), (60.0, False), (None, False)])
def test_warning_opens_a_condition_based_order_only_within_the_horizon(env, days, opens):
    factory, axis_id = env
    cycle, alerts = _store(factory, axis_id, 226.0)
    assert cycle.state == "WARNING"
    _loop(factory, days).after_cycle(axis_id, cycle, alerts)
    with session_scope(factory) as s:
        o = maintenance_repo.active_order(s, axis_id)
    if not opens:
        assert o is None
        return
    assert o.kind == "condition_based" and o.state == "open" and o.alert_id is None
    assert o.due_at is not None and abs((o.due_at - datetime.now(timezone.utc)).total_seconds() - 10 * DAY) < 120
    assert "condition-based maintenance" in o.recommendation and "30-day horizon" in o.recommendation


def test_ok_opens_nothing_alarm_opens_one_corrective_order_and_only_one(env):
    factory, axis_id = env
    loop = _loop(factory, 5.0)
    cycle, alerts = _store(factory, axis_id, 150.0)
    loop.after_cycle(axis_id, cycle, alerts)
    with session_scope(factory) as s:
        assert maintenance_repo.active_order(s, axis_id) is None
    seen = []
    loop.service.events.subscribe("t", seen.append)
    for _ in range(2):
        cycle, alerts = _store(factory, axis_id, 260.0)
        loop.after_cycle(axis_id, cycle, alerts)
    with session_scope(factory) as s:
        total, (o,) = maintenance_repo.list_orders(s, "all", axis_id=axis_id)
    assert total == 1 and o.kind == "corrective" and o.alert_id is not None
    assert o.restore_below_um == pytest.approx(o.backlash_limit_um * 0.9)
    loop.service.events.close()
    assert [e.kind for e in seen] == ["work_order_changed"]


def test_verify_at_a_configured_time():
    now = datetime(2026, 5, 4, 10, 30, tzinfo=timezone.utc)
    assert next_verify_time("now", now) is None
    assert next_verify_time("22:00", now) == datetime(2026, 5, 4, 22, 0, tzinfo=timezone.utc)
    assert next_verify_time("06:15", now) == datetime(2026, 5, 5, 6, 15, tzinfo=timezone.utc)
    assert next_verify_time("10:30", now) == now + timedelta(days=1)


def test_maintenance_and_wear_settings_are_read_and_checked():
    from api.service.config.loading import parse_settings
    from api.service.config.settings import DEMO_SIMULATOR, ConfigError, default_settings

    s = parse_settings({"maintenance": {"horizon_days": 14, "verify_at": "06:00", "fixed_interval_days": 60},
                        "simulator": {"wear_um_per_day": 2.5, "utility_days_per_s": 0.5}})
    assert (s.maintenance.horizon_days, s.maintenance.verify_at, s.maintenance.fixed_interval_days) == (14, "06:00", 60)
    assert (s.simulator.wear_um_per_day, s.simulator.utility_days_per_s) == (2.5, 0.5)
    for bad, what in (({"maintenance": {"verify_at": "25:00"}}, "verify_at"),
                      ({"maintenance": {"fixed_interval_days": 0}}, "fixed_interval_days"),
                      ({"maintenance": {"horizon_days": -1}}, "horizon_days"),
                      ({"maintenance": {"horizon": 3}}, "horizon"),
                      ({"simulator": {"wear_um_per_day": -1}}, "wear_um_per_day"),
                      ({"simulator": {"utility_days_per_s": 0}}, "utility_days_per_s")):
        with pytest.raises(ConfigError, match=what):
            parse_settings(bad)
    # make run's demo wears; a file with machines of its own starts from the plain simulator
    assert default_settings().simulator == DEMO_SIMULATOR and DEMO_SIMULATOR.wear_um_per_day > 0
    own = parse_settings({"machines": [{"name": "m"}], "simulator": {"time_scale": 5}}, base=default_settings())
    assert own.simulator.wear_um_per_day == 0.0 and own.simulator.backlash_um_at_20c == 226.0


def test_a_restart_concludes_a_stored_but_unjudged_verification(env):
    factory, axis_id = env
    loop = _loop(factory, None)
    cycle, alerts = _store(factory, axis_id, 260.0)
    loop.after_cycle(axis_id, cycle, alerts)
    with session_scope(factory) as s:
        repair, order = maintenance_repo.record_repair(s, axis_id, "nut_replaced", by="bob")
    verification, _ = _store(factory, axis_id, 150.0)  # stored; then the service stopped before judging it
    with session_scope(factory) as s:
        maintenance_repo.set_verification_cycle(s, order.id, verification.id)
    loop.resume()
    with session_scope(factory) as s:
        o = maintenance_repo.get_order(s, order.id)
    assert o.state == "verified" and o.verification["after"]["measurement_id"] == verification.id
    assert o.verification["before"]["measurement_id"] == cycle.id
