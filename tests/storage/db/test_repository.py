"""Repository round trips on SQLite and PostgreSQL: what is written is read back."""

from __future__ import annotations

import math
from dataclasses import replace
from datetime import datetime, timedelta, timezone

import numpy as np
import pytest

from core.errors import InputError
from storage.db import (
    ConflictError,
    NotFoundError,
    Schedule,
    config_repo,
    integrity_problems,
    make_session_factory,
    results_repo,
    session_scope,
)
from tests.storage.db import factories as f


@pytest.fixture
def factory(engine):
    return make_session_factory(engine)


@pytest.fixture
def axis_id(factory):
    with session_scope(factory) as s:
        m = config_repo.create_machine(s, "vmc-850", "test machine")
        return config_repo.create_axis(s, m.id, f.settings()).id


def test_machine_and_axis_round_trip(factory, axis_id):
    with session_scope(factory) as s:
        (m,) = config_repo.list_machines(s)
        assert m.name == "vmc-850" and m.axis_ids == (axis_id,)
        a = config_repo.get_axis(s, axis_id)
    assert a.spec == f.AXIS
    assert a.tasks == (f.CIRCLE,)
    assert a.settings.schedule == Schedule(interval_s=60.0)
    assert a.settings.in_service_since.tzinfo is not None


def test_an_axis_keeps_its_instruments_and_one_stored_without_them_has_the_defaults(factory, axis_id):
    from core.criteria.uncertainty import Instruments
    from storage.db.models import Axis

    mine = Instruments(scale_accuracy_um=2.0, scale_accuracy_um_per_m=3.0, thermometer_class="A",
                       thermal_expansion_per_k=10.5e-6)
    with session_scope(factory) as s:
        m = config_repo.create_machine(s, "lathe")
        other = config_repo.create_axis(s, m.id, replace(f.settings(), instruments=mine)).id
    with session_scope(factory) as s:
        assert config_repo.get_axis(s, other).settings.instruments == mine
        row = s.get(Axis, axis_id)
        row.scale_accuracy_um = row.scale_accuracy_um_per_m = row.thermometer_class = None
        row.thermal_expansion_per_k = None
    with session_scope(factory) as s:
        assert config_repo.get_axis(s, axis_id).settings.instruments == Instruments()


def test_duplicates_and_unknown_ids_are_named(factory, axis_id):
    with pytest.raises(ConflictError, match="vmc-850"), session_scope(factory) as s:
        config_repo.create_machine(s, "vmc-850")
    with pytest.raises(NotFoundError, match="axis"), session_scope(factory) as s:
        config_repo.get_axis(s, 999)
    with pytest.raises(InputError, match="unique"), session_scope(factory) as s:
        config_repo.set_tasks(s, axis_id, [f.CIRCLE, f.CIRCLE])


def test_tasks_are_replaced(factory, axis_id):
    with session_scope(factory) as s:
        a = config_repo.set_tasks(s, axis_id, [f.LINE, f.CIRCLE])
    assert [t.name for t in a.tasks] == [f.LINE.name, f.CIRCLE.name]
    with session_scope(factory) as s:
        assert config_repo.get_axis(s, axis_id).tasks == (f.LINE, f.CIRCLE)


def test_result_is_stored_with_curves_and_read_back(factory, axis_id):
    fc = f.finished(axis_id, 180.0, tasks=(f.CIRCLE, f.LINE))
    with session_scope(factory) as s:
        cycle, alerts = results_repo.save_finished_cycle(s, fc)
    assert cycle.status == "ok" and alerts == []
    with session_scope(factory) as s:
        c, r = results_repo.get_measurement(s, cycle.id)
    rt = fc.round_trip
    assert r.round_trip.backlash.mean_um == pytest.approx(rt.backlash.mean_um)
    assert r.round_trip.backlash.mean_um == pytest.approx(180.0, abs=3.0)
    np.testing.assert_allclose(r.round_trip.backlash.backlash_um, rt.backlash.backlash_um, atol=1e-3)
    np.testing.assert_allclose(r.round_trip.backlash.position_mm, rt.backlash.position_mm, atol=1e-9)
    for d in ("positive", "negative"):
        assert r.round_trip.strokes[d].v_u_um == pytest.approx(rt.strokes[d].v_u_um)
        np.testing.assert_allclose(r.round_trip.strokes[d].travel_deviation_um,
                                   rt.strokes[d].travel_deviation_um, atol=1e-3)
    assert [t.task.name for t in r.tbe] == [f.CIRCLE.name, f.LINE.name]
    assert r.tbe[0].tbe_um == pytest.approx(float(f.CIRCLE.tbe_um(rt.backlash.mean_um)))
    assert r.tbe[0].backlash_limit_um == pytest.approx(236.0, abs=0.1)
    assert c.uncertainty_um == 1.5 and c.temperature_c == 20.0


def test_save_is_idempotent_on_uuid(factory, axis_id):
    fc = f.finished(axis_id, 100.0)
    with session_scope(factory) as s:
        first, _ = results_repo.save_finished_cycle(s, fc)
    with session_scope(factory) as s:
        again, _ = results_repo.save_finished_cycle(s, fc)
        total, page = results_repo.list_measurements(s, axis_id)
    assert again.id == first.id and total == 1


def test_alert_raised_once_then_cleared_and_acknowledged(factory, axis_id):
    t0 = datetime(2026, 1, 1, tzinfo=timezone.utc)
    seq = [200.0, 250.0, 252.0, 220.0]
    changes = []
    for i, b in enumerate(seq):
        with session_scope(factory) as s:
            _, ch = results_repo.save_finished_cycle(s, f.finished(axis_id, b, when=t0 + timedelta(hours=i)))
        changes.append(ch)
    assert changes[0] == [] and changes[2] == []
    (raised,) = changes[1]
    (cleared,) = changes[3]
    assert raised.id == cleared.id and cleared.cleared_at == t0 + timedelta(hours=3)
    assert raised.backlash_limit_um == pytest.approx(236.0, abs=0.1)
    assert raised.tbe_um > 45.0 and "restore" in raised.message
    with session_scope(factory) as s:
        assert results_repo.list_alerts(s, "active")[0] == 0
        total, (a,) = results_repo.list_alerts(s, "cleared")
        acked = results_repo.acknowledge_alert(s, a.id, "maintenance")
        assert results_repo.acknowledge_alert(s, a.id, "someone else").acknowledged_by == "maintenance"
    assert acked.acknowledged_by == "maintenance" and acked.raised_by_measurement_id is not None


def test_failed_cycle_is_kept_with_its_reason(factory, axis_id):
    fc = f.finished(axis_id, None, status="failed", reason="no answer from modbus://x within 1 s")
    with session_scope(factory) as s:
        c, _ = results_repo.save_finished_cycle(s, fc)
        total, (row,) = results_repo.list_measurements(s, axis_id, status="failed")
        assert results_repo.latest_result(s, axis_id) is None
    assert row.failure_reason.startswith("no answer") and c.status == "failed"


def test_trend_pagination_and_time_filter(factory, axis_id):
    t0 = datetime(2026, 1, 1, tzinfo=timezone.utc)
    for i in range(5):
        with session_scope(factory) as s:
            results_repo.save_finished_cycle(
                s, f.finished(axis_id, 150.0 + 10 * i, when=t0 + timedelta(days=i), temperature_c=10.0 + i))
    with session_scope(factory) as s:
        tr = results_repo.trend(s, axis_id).series
        total, page = results_repo.list_measurements(s, axis_id, limit=2, offset=1)
        _, recent = results_repo.list_measurements(s, axis_id, since=t0 + timedelta(days=3, hours=-1))
        sums = results_repo.backlash_history(s, axis_id)
        hist = results_repo.tbe_history(s, axis_id)
        latest = results_repo.latest_result(s, axis_id)
    assert len(tr.backlash_mean_um) == 5 and list(tr.temperature_c) == [10.0, 11.0, 12.0, 13.0, 14.0]
    assert tr.measured_at[0] == t0 and tr.backlash_mean_um[4] > tr.backlash_mean_um[0]
    assert total == 5 and len(page) == 2 and page[0].finished_at == t0 + timedelta(days=3)
    assert len(recent) == 2
    assert sums.n == 5 and (sums.x_min, sums.x_max) == (10.0, 14.0) and len(hist) == 5
    assert latest.measured_at == t0 + timedelta(days=4)


def test_stale_cycles_are_closed_at_start_up(factory, axis_id):
    with session_scope(factory) as s:
        results_repo.queue_cycle(s, axis_id, "u-1", "manual", requested_by="op")
        results_repo.queue_cycle(s, axis_id, "u-2", "schedule")
        results_repo.mark_running(s, "u-1")
    with session_scope(factory) as s:
        assert results_repo.close_stale_cycles(s) == 2
        _, rows = results_repo.list_measurements(s, axis_id)
    assert sorted(r.status for r in rows) == ["cancelled", "interrupted"]


def test_a_cycle_that_finished_and_waits_in_the_spool_is_closed_with_its_reason_and_not_counted_as_interrupted(
        factory, axis_id):
    with session_scope(factory) as s:
        results_repo.queue_cycle(s, axis_id, "u-kept", "manual")
        results_repo.mark_running(s, "u-kept")
        results_repo.queue_cycle(s, axis_id, "u-cut", "schedule")
        results_repo.mark_running(s, "u-cut")
    reason = "storage_full: the disk under the data folder was full when the cycle finished"
    with session_scope(factory) as s:
        assert results_repo.close_stale_cycles(s, held={"u-kept": ("ok", reason)}) == 1  # u-cut only
        _, rows = results_repo.list_measurements(s, axis_id)
    by_status = {r.status: r.failure_reason for r in rows}
    assert by_status == {"failed": reason, "interrupted": "the service stopped during the cycle"}


def test_keys_are_hashed_and_revocable(factory, engine):
    with session_scope(factory) as s:
        rec, secret = config_repo.create_key(s, "mes", "read")
    assert secret.startswith("mebm_") and len(secret) > 40
    with engine.connect() as c:
        stored = c.exec_driver_sql("SELECT key_sha256 FROM api_keys").scalar_one()
    assert secret not in stored and stored == config_repo.hash_key(secret)
    with session_scope(factory) as s:
        assert config_repo.authenticate(s, secret).role == "read"
        assert config_repo.authenticate(s, secret + "x") is None
        config_repo.revoke_key(s, rec.id)
        assert config_repo.authenticate(s, secret) is None
    with pytest.raises(InputError, match="role"), session_scope(factory) as s:
        config_repo.create_key(s, "bad", "root")


def test_integrity_check_passes_and_metrics_count(factory, engine, axis_id):
    with session_scope(factory) as s:
        results_repo.save_finished_cycle(s, f.finished(axis_id, 250.0))
        results_repo.save_finished_cycle(s, f.finished(axis_id, None, status="failed", reason="x"))
        snap = results_repo.metrics_snapshot(s)
    assert integrity_problems(engine) == []
    assert snap["cycles"][(axis_id, "ok")] == 1 and snap["cycles"][(axis_id, "failed")] == 1
    assert snap["active_alerts"][axis_id] == 1


def test_schedule_validation():
    with pytest.raises(InputError, match="interval_s"):
        Schedule(interval_s=0.1)
    with pytest.raises(InputError, match="cron"):
        Schedule(cron="* *")
    assert not Schedule().active
    assert replace(Schedule(interval_s=5), enabled=False).active is False
    assert math.isfinite(Schedule(interval_s=5).interval_s)


def test_metrology_of_a_result_is_stored_and_read_back(factory, axis_id):
    # the GUM budgets, outliers, grid, TBE uncertainty and the decision rule
    from core.tbe import decide

    fc = f.finished(axis_id, 180.0, tasks=())
    rt = fc.round_trip
    dec = decide(rt.backlash.mean_um, (f.CIRCLE,), backlash_uncertainty_um=rt.backlash_mean_uncertainty_um)
    fc = replace(fc, decision=dec)
    with session_scope(factory) as s:
        cycle, _ = results_repo.save_finished_cycle(s, fc)
    with session_scope(factory) as s:
        _, r = results_repo.get_measurement(s, cycle.id)
    got = r.round_trip
    assert got.budgets.keys() == rt.budgets.keys()
    assert got.backlash_mean_uncertainty_um == pytest.approx(rt.backlash_mean_uncertainty_um)
    assert got.criterion_uncertainty_um("negative", "v_2pi") == pytest.approx(rt.criterion_uncertainty_um("negative", "v_2pi"))
    assert got.outliers_removed == rt.outliers_removed and got.grid_step_mm == rt.grid_step_mm
    assert r.decision_rule == "guarded" and r.tbe[0].decision_rule == "guarded"
    assert r.tbe[0].tbe_uncertainty_um == pytest.approx(dec.assessments[0].tbe_uncertainty_um)
    assert r.tbe[0].backlash_limit_uncertainty_um == pytest.approx(dec.assessments[0].backlash_limit_uncertainty_um)
    assert r.tbe[0].tbe_uncertainty_um > 0
