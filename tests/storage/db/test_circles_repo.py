"""Circular tests stored on SQLite and PostgreSQL: the test with its samples comes back
as it was stored, lists are per machine and per axis, newest first, and a test's decision
raises and clears its own alert. Migration 0012 keeps the rows stored before it."""

from __future__ import annotations

from dataclasses import replace
from datetime import datetime, timedelta, timezone

import numpy as np
import pytest
from sqlalchemy import inspect, text

from core.circle.test import CirclePass, CircularTest, Instrument
from core.errors import InputError
from storage.db import (
    NotFoundError,
    OrderRequest,
    circles_repo,
    config_repo,
    maintenance_repo,
    make_engine,
    make_session_factory,
    results_repo,
    session_scope,
    upgrade,
)
from tests.storage.db import factories as f
from tests.storage.db.backends import BACKENDS, make_database
from tests.storage.db.test_identities import downgrade

T0 = datetime(2026, 3, 1, 8, 0, tzinfo=timezone.utc)


def circle(radius_mm=200.0, feed_mm_min=200.0, *, spike_um=12.0, plane=("x", "y"), seed=0) -> CircularTest:
    """Both directions of a circle with a reversal spike after each quadrant."""
    rng = np.random.default_rng(seed)
    passes = []
    for direction in ("ccw", "cw"):
        run = np.arange(0.0, 360.0, 0.5)
        ang = run if direction == "ccw" else (360.0 - run) % 360.0
        rad = rng.normal(0.0, 0.3, ang.size)
        for q in (0.0, 90.0, 180.0, 270.0):
            after = (ang - q) % 360.0 if direction == "ccw" else (q - ang) % 360.0
            rad += spike_um * np.exp(-after / 2.0) * (after < 20.0)
        passes.append(CirclePass(direction, ang, rad))
    return CircularTest(radius_mm=radius_mm, feed_mm_min=feed_mm_min, plane=plane, passes=tuple(passes),
                        instrument=Instrument("encoders", 0.1, 0.5, "linear scales"), temperature_c=21.5,
                        utility_day=3.25, source="simulated: test")


@pytest.fixture
def factory(engine):
    return make_session_factory(engine)


@pytest.fixture
def axes(factory):
    """{name: id} of machine vmc-850's x and y, and a second machine's x."""
    with session_scope(factory) as s:
        m = config_repo.create_machine(s, "vmc-850")
        other = config_repo.create_machine(s, "lathe-2")
        out = {n: config_repo.create_axis(s, m.id, f.settings(spec=replace(f.AXIS, name=n))).id for n in ("x", "y")}
        out["other.x"] = config_repo.create_axis(s, other.id, f.settings(spec=replace(f.AXIS, name="x"))).id
    return out


def _decision(state: str, error_um: float) -> dict:
    return {"state": state, "task": "circle R200", "error_um": error_um, "uncertainty_um": 0.8,
            "tolerance_um": 45.0, "reason": f"measured TBE {error_um} µm against 45 µm"}


def test_a_stored_test_comes_back_with_its_samples_and_analysis(factory, axes):
    test = circle()
    figures = {"circular_deviation_um": 14.2, "circular_deviation_uncertainty_um": 0.9, "hysteresis_um": float("nan")}
    with session_scope(factory) as s:
        tid = circles_repo.add_circular_test(
            s, "vmc-850", test, figures=figures, agreement={"y": {"verdict": "agree", "normalised_error": 0.4}},
            decision={"x": None, "y": _decision("WARNING", 41.0)}, measured_at=T0, recorded_by="op")
    with session_scope(factory) as s:
        rec = circles_repo.get_circular_test(s, tid)
    assert rec.test == test  # the samples, instrument, plane, R, F as stored
    assert (rec.plane, rec.axis_ids, rec.directions) == (("x", "y"), (axes["x"], axes["y"]), ("ccw", "cw"))
    assert (rec.radius_mm, rec.feed_mm_min, rec.temperature_c, rec.utility_day) == (200.0, 200.0, 21.5, 3.25)
    assert rec.measured_at == T0 and rec.machine_name == "vmc-850" and rec.source == "simulated: test"
    assert rec.figures["circular_deviation_um"] == 14.2 and rec.figures["hysteresis_um"] is None  # NaN: null
    assert rec.agreement["y"]["verdict"] == "agree" and rec.decision == {"x": None, "y": _decision("WARNING", 41.0)}
    assert rec.state == "WARNING" and rec.axis_id_of("y") == axes["y"] and rec.axis_id_of("z") is None
    assert rec.instrument == {"kind": "encoders", "resolution_um": 0.1, "accuracy_um": 0.5, "name": "linear scales"}


def test_the_engine_form_runs_in_its_own_transaction(engine, axes):
    tid = circles_repo.add_circular_test(engine, "vmc-850", circle(), measured_at=T0)
    assert circles_repo.get_circular_test(engine, tid).state is None  # nothing judged
    assert [r.id for r in circles_repo.list_circular_tests(engine, "vmc-850")] == [tid]


def test_lists_are_per_machine_and_axis_newest_first_without_samples_unless_asked(factory, axes):
    with session_scope(factory) as s:
        ids = [circles_repo.add_circular_test(s, "vmc-850", circle(seed=i), measured_at=T0 + timedelta(hours=i))
               for i in range(3)]
    with session_scope(factory) as s:
        listed = circles_repo.list_circular_tests(s, "vmc-850")
        machine_id = config_repo.get_axis(s, axes["x"]).machine_id
        by_id = circles_repo.list_circular_tests(s, machine_id, axis=axes["y"], limit=2)
        by_name = circles_repo.list_circular_tests(s, "vmc-850", axis="x", samples=True)
        latest = circles_repo.latest_circular_test(s, axes["y"])
        none_other = circles_repo.list_circular_tests(s, "lathe-2", axis="x")
        n = circles_repo.count_circular_tests(s, "vmc-850", "y")
    assert [r.id for r in listed] == ids[::-1] and all(r.test is None for r in listed)
    assert [r.id for r in by_id] == ids[:0:-1]
    assert [r.id for r in by_name] == ids[::-1] and by_name[0].test == circle(seed=2)
    assert latest.id == ids[-1] and none_other == [] and n == 3


def test_unknown_machine_axis_or_plane_is_refused_by_name(factory, axes):
    with session_scope(factory) as s:
        with pytest.raises(NotFoundError):
            circles_repo.add_circular_test(s, "no-such", circle())
        with pytest.raises(InputError, match="no axis 'z'"):
            circles_repo.add_circular_test(s, "vmc-850", circle(plane=("x", "z")))
        with pytest.raises(InputError, match="not in the plane"):
            circles_repo.add_circular_test(s, "vmc-850", circle(), decision={"z": None})
        with pytest.raises(NotFoundError):
            circles_repo.list_circular_tests(s, "vmc-850", axis=axes["other.x"])  # another machine's axis
        with pytest.raises(NotFoundError):
            circles_repo.get_circular_test(s, 999)


def test_a_test_raises_its_own_alert_and_the_next_test_below_alarm_clears_it(factory, axes):
    y = axes["y"]
    with session_scope(factory) as s:
        t1 = circles_repo.add_circular_test(s, "vmc-850", circle(spike_um=50.0), measured_at=T0)
        raised = circles_repo.update_alerts(s, y, t1, _decision("ALARM", 50.0), at=T0)
        again = circles_repo.update_alerts(s, y, t1, _decision("ALARM", 51.0), at=T0)  # one while active
        # a round trip of the axis judged OK does not clear the test's alert
        results_repo.save_finished_cycle(s, f.finished(y, 20.0, when=T0 + timedelta(minutes=5)))
    assert len(raised) == 1 and again == []
    a = raised[0]
    assert (a.kind, a.active, a.raised_by_circular_test_id, a.task_name, a.tbe_um, a.tolerance_um) == (
        "tbe_exceeded", True, t1, "circle R200", 50.0, 45.0)
    assert f"circular test {t1}" in a.message
    with session_scope(factory) as s:
        assert [x.id for x in results_repo.list_alerts(s, axis_id=y)[1]] == [a.id]
        t2 = circles_repo.add_circular_test(s, "vmc-850", circle(spike_um=5.0), measured_at=T0 + timedelta(hours=1))
        assert circles_repo.update_alerts(s, y, t2, None) == []  # no task judged: nothing changes
        cleared = circles_repo.update_alerts(s, y, t2, _decision("OK", 5.0), at=T0 + timedelta(hours=1))
    assert [(c.id, c.active, c.cleared_by_circular_test_id) for c in cleared] == [(a.id, False, t2)]


def test_an_order_names_the_test_that_opened_it(factory, axes):
    with session_scope(factory) as s:
        tid = circles_repo.add_circular_test(s, "vmc-850", circle(spike_um=50.0), measured_at=T0)
        order, created = maintenance_repo.open_order(s, OrderRequest(
            axis_id=axes["y"], kind="corrective", opened_at=T0, recommendation="restore", circular_test_id=tid))
    assert created and order.opened_by_circular_test_id == tid and order.opened_by_measurement_id is None


@pytest.mark.parametrize("backend", BACKENDS)
def test_the_migration_keeps_the_alerts_and_orders_stored_before_it(backend, tmp_path):
    url, handle = make_database(backend, tmp_path)
    engine = make_engine(url)
    try:
        upgrade(engine, "0011")
        with session_scope(make_session_factory(engine)) as s:
            m = config_repo.create_machine(s, "vmc-850")
            axis_id = config_repo.create_axis(s, m.id, f.settings()).id
        with engine.begin() as c:  # as 0011 stored them: no evidence columns yet
            c.execute(text("INSERT INTO alerts (axis_id, kind, raised_at, message) VALUES (:a, 'tbe_exceeded', :t, 'm')"),
                      {"a": axis_id, "t": T0})
            alert_id = c.execute(text("SELECT id FROM alerts")).scalar_one()
            c.execute(text("INSERT INTO work_orders (axis_id, kind, state, opened_at, alert_id, recommendation) "
                           "VALUES (:a, 'corrective', 'open', :t, :al, 'r')"), {"a": axis_id, "t": T0, "al": alert_id})
        upgrade(engine)
        with session_scope(make_session_factory(engine)) as s:
            order = maintenance_repo.active_order(s, axis_id)
            alerts = results_repo.list_alerts(s, axis_id=axis_id)[1]
        assert order.alert_id == alert_id and order.opened_by_circular_test_id is None
        assert [(x.id, x.raised_by_circular_test_id) for x in alerts] == [(alert_id, None)]
        downgrade(engine, "0011")  # and back: the rows stay, the table goes
        with engine.connect() as c:
            assert c.execute(text("SELECT alert_id FROM work_orders")).scalar_one() == alert_id
            assert "circular_tests" not in inspect(c).get_table_names()
            assert "raised_by_circle_id" not in {col["name"] for col in inspect(c).get_columns("alerts")}
        upgrade(engine)
    finally:
        engine.dispose()
        if handle is not None:
            handle.drop()


def test_two_tests_in_alarm_stored_together_raise_one_alert(factory, axes):
    """Both transactions are open and have stored their test before either looks for the
    axis' active alert: the axis row's lock (PostgreSQL; SQLite's one writer) orders them."""
    import threading

    y = axes["y"]
    barrier = threading.Barrier(2, timeout=30)
    raised, errors = [], []

    def post(i):
        try:
            with session_scope(factory) as s:
                tid = circles_repo.add_circular_test(s, "vmc-850", circle(spike_um=50.0, seed=i), measured_at=T0)
                if s.bind.dialect.name == "postgresql":
                    barrier.wait()  # (SQLite: the first insert holds the one write lock until its commit)
                raised.extend(circles_repo.update_alerts(s, y, tid, _decision("ALARM", 50.0), at=T0))
        except Exception as exc:  # noqa: BLE001 - reported below
            errors.append(exc)

    threads = [threading.Thread(target=post, args=(i,)) for i in range(2)]
    for t in threads:
        t.start()
    for t in threads:
        t.join(60)
    assert errors == [] and len(raised) == 1
    with session_scope(factory) as s:
        active = results_repo.list_alerts(s, axis_id=y)[1]
    assert [a.id for a in active] == [raised[0].id]
