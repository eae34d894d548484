"""Work orders and repairs on SQLite and PostgreSQL: one active order per axis
is the database's rule (two ALARMs at once still open one), every step is stored with
its time, who and why, a repair moves the order and is found again."""

from __future__ import annotations

import threading
from datetime import datetime, timedelta, timezone

import pytest
from sqlalchemy.exc import IntegrityError

from core.errors import InputError
from core.maintenance import TransitionError
from storage.db import (
    OrderRequest,
    config_repo,
    maintenance_repo,
    make_session_factory,
    results_repo,
    session_scope,
)
from storage.db.models import WorkOrder
from tests.storage.db import factories as f

T0 = datetime(2026, 3, 1, 8, 0, tzinfo=timezone.utc)


@pytest.fixture
def factory(engine):
    return make_session_factory(engine)


@pytest.fixture
def axis_id(factory):
    with session_scope(factory) as s:
        m = config_repo.create_machine(s, "vmc-850")
        return config_repo.create_axis(s, m.id, f.settings()).id


def _req(axis_id: int, when=T0, kind="corrective") -> OrderRequest:
    return OrderRequest(axis_id=axis_id, kind=kind, opened_at=when, recommendation="restore below 200 µm",
                        binding_task="circle R200", tolerance_um=45.0, backlash_um=250.0, backlash_uncertainty_um=2.0,
                        tbe_um=47.0, tbe_uncertainty_um=0.4, backlash_limit_um=236.0, restore_below_um=212.4)


def test_the_database_refuses_a_second_active_order_on_an_axis(factory, axis_id):
    with session_scope(factory) as s:
        first, created = maintenance_repo.open_order(s, _req(axis_id))
    assert created and first.state == "open"
    # bypassing the repository: the partial unique index itself refuses it
    with pytest.raises(Exception) as err, session_scope(factory) as s:
        s.add(WorkOrder(axis_id=axis_id, kind="corrective", state="acknowledged", opened_at=T0, recommendation="x"))
        s.flush()
    assert isinstance(err.value.__cause__, IntegrityError)
    # a closed order does not count: after cancelling, a new one opens
    with session_scope(factory) as s:
        maintenance_repo.transition(s, first.id, "cancel", by="op", note="false alarm: probe loose")
        second, created = maintenance_repo.open_order(s, _req(axis_id, T0 + timedelta(hours=1)))
    assert created and second.id != first.id


def test_two_alarms_arriving_together_open_one_order(factory, axis_id, monkeypatch):
    """Both threads pass the "is one active?" check before either inserts (the race the
    check alone would lose); the unique index decides and the loser gets the winner's order."""
    real = maintenance_repo._active
    barrier = threading.Barrier(2, timeout=30)
    first_call = threading.local()

    def racing_active(s, axis):
        if not getattr(first_call, "done", False):
            first_call.done = True
            barrier.wait()  # both are past the check now
            return None
        return real(s, axis)

    monkeypatch.setattr(maintenance_repo, "_active", racing_active)
    results, errors = [], []

    def alarm(i):
        try:
            with session_scope(factory) as s:
                results.append(maintenance_repo.open_order(s, _req(axis_id, T0 + timedelta(seconds=i))))
        except Exception as exc:  # noqa: BLE001 - reported below
            errors.append(exc)

    threads = [threading.Thread(target=alarm, args=(i,)) for i in range(2)]
    for t in threads:
        t.start()
    for t in threads:
        t.join(60)
    assert not errors, errors
    assert sorted(c for _, c in results) == [False, True]
    assert len({o.id for o, _ in results}) == 1
    monkeypatch.setattr(maintenance_repo, "_active", real)
    with session_scope(factory) as s:
        total, rows = maintenance_repo.list_orders(s, "all", axis_id=axis_id)
    assert total == 1 and len(rows[0].transitions) == 1


def test_every_step_is_stored_with_time_who_and_note(factory, axis_id):
    with session_scope(factory) as s:
        o, _ = maintenance_repo.open_order(s, _req(axis_id))
        maintenance_repo.transition(s, o.id, "acknowledge", by="anna", note="parts ordered",
                                    when=T0 + timedelta(minutes=5))
    with session_scope(factory) as s:
        repair, order = maintenance_repo.record_repair(s, axis_id, "preload_adjusted", by="bob",
                                                       note="nut preload +1 turn", performed_at=T0 + timedelta(hours=2))
    assert order.state == "repaired" and repair.order_id == o.id and repair.recorded_by == "bob"
    with session_scope(factory) as s:
        with pytest.raises(TransitionError, match="'repaired'.*cannot be acknowledged"):
            maintenance_repo.transition(s, o.id, "acknowledge", by="anna")
        v = {"passed": False, "message": "TBE still 46 µm", "before": {"b": 250}, "after": {"b": 240}}
        back = maintenance_repo.conclude_verification(s, o.id, passed=False, verification=v, note="not verified")
    assert back.state == "open" and back.closed_at is None
    assert [(t.from_state, t.to_state, t.by) for t in back.transitions] == [
        (None, "open", "mebm"), ("open", "acknowledged", "anna"), ("acknowledged", "repaired", "bob"),
        ("repaired", "open", "mebm")]
    assert back.transitions[1].note == "parts ordered" and back.transitions[1].at == T0 + timedelta(minutes=5)
    assert back.transitions[2].note == "preload_adjusted: nut preload +1 turn"
    assert back.transitions[3].figures == v and back.verification == v
    with session_scope(factory) as s:
        with pytest.raises(InputError, match="reason"):
            maintenance_repo.transition(s, o.id, "cancel", by="anna", note="  ")
        done = maintenance_repo.transition(s, o.id, "cancel", by="anna", note="machine scrapped")
    assert done.state == "cancelled" and done.closed_at is not None and not done.active


def test_repairs_compensation_reference_and_last_repair(factory, axis_id):
    with session_scope(factory) as s:
        c1, _ = results_repo.save_finished_cycle(s, f.finished(axis_id, 180.0, when=T0))
        with pytest.raises(InputError, match="kind"):
            maintenance_repo.record_repair(s, axis_id, "hammered", by="bob")
        with pytest.raises(InputError, match="only for a repair of kind 'compensation_loaded'"):
            maintenance_repo.record_repair(s, axis_id, "lubricated", by="bob", compensation_measurement_id=c1.id)
        with pytest.raises(InputError, match="not an ok measurement"):
            maintenance_repo.record_repair(s, axis_id, "compensation_loaded", by="bob",
                                           compensation_measurement_id=c1.id + 100)
        r, order = maintenance_repo.record_repair(s, axis_id, "compensation_loaded", by="bob",
                                                  performed_at=T0 + timedelta(hours=1))
    assert order is None  # no order open: recorded all the same
    assert r.compensation_measurement_id == c1.id and r.before_measurement_id == c1.id
    with session_scope(factory) as s:
        assert maintenance_repo.last_repair_at(s, axis_id) == T0 + timedelta(hours=1)
        assert [x.id for x in maintenance_repo.list_repairs(s, axis_id)] == [r.id]
        fig = maintenance_repo.figures(s, c1.id)
    assert abs(fig.backlash_mean_um - 180.0) < 3.0 and fig.tasks[0]["task"] == "circle R200"
    assert set(fig.lead) == {"e_p_um_per_1000mm", "v_u_um", "v_300_um", "v_2pi_um"}


def test_the_prognosis_rows_start_after_the_last_repair(factory, axis_id):
    with session_scope(factory) as s:
        for i in range(6):
            results_repo.save_finished_cycle(s, f.finished(axis_id, 150.0 + i, when=T0 + timedelta(hours=i),
                                                           temperature_c=20.0 + i))
        maintenance_repo.record_repair(s, axis_id, "nut_replaced", by="bob", performed_at=T0 + timedelta(hours=3, minutes=30))
        since = maintenance_repo.last_repair_at(s, axis_id)
        rows = results_repo.history_rows(s, axis_id, since=since)
        every = results_repo.history_rows(s, axis_id)
    assert every["temperature_c"].tolist() == [20.0, 21.0, 22.0, 23.0, 24.0, 25.0]
    assert rows["temperature_c"].tolist() == [24.0, 25.0] and int(rows["total"]) == 2
