"""Hourly trend rollups: the trend of a long history read from whole hours and
the rows of the partial hours at the range's edges gives the correlations and the thermal
model of every row, keeps every excursion of b̄ on the screen, follows each stored result,
and is built by the migration for results stored before it. SQLite and PostgreSQL."""

from __future__ import annotations

import uuid
from datetime import datetime, timedelta, timezone

import numpy as np
import pytest
from sqlalchemy import func, insert, select, text

from core.history import TemperatureModel, pearson_r
from storage.db import config_repo, make_session_factory, results_repo, session_scope, upgrade
from storage.db import rollup
from storage.db.models import Axis, Cycle, LeadCriteriaRow, Machine, Result, TbeRow, TrendRollup
from tests.storage.db import factories as f
from tests.storage.db.backends import BACKENDS, make_database

T0 = datetime(2026, 3, 1, 0, 0, 30, tzinfo=timezone.utc)
N = 3 * 1440  # three days of one-minute results
SPIKE = 2000  # the one measurement far above the rest
CYCLE_OFFSET = 500_000  # cycle ids (the measurement ids of the API) differ from result ids


def _history(n=N, seed=0):
    rng = np.random.default_rng(seed)
    i = np.arange(n)
    temp = 20.0 + 6.0 * np.sin(2 * np.pi * i / 1440.0) + rng.normal(0, 0.3, n)
    b = 220.0 + 2.0 * (temp - 20.0) + rng.normal(0, 1.0, n)
    b[SPIKE % n] = 300.0
    temp[7] = np.nan  # a cycle without a thermometer reading
    return i, temp, b


def bulk_load_results(engine, axis_id, i, temp, b, step=timedelta(minutes=1)):
    """Rows as a bulk load writes them (no rollups): cycles, results, both lead rows."""
    when = [T0 + int(k) * step for k in i]
    tc = [None if not np.isfinite(x) else float(x) for x in temp]
    with engine.begin() as c:
        c.execute(insert(Cycle), [dict(id=int(k) + 1 + CYCLE_OFFSET, uuid=str(uuid.uuid4()), axis_id=axis_id, trigger="schedule",
                                       status="ok", requested_at=w, started_at=w, finished_at=w)
                                  for k, w in zip(i, when)])  # fmt: skip
        c.execute(insert(Result), [dict(
            id=int(k) + 1, cycle_id=int(k) + 1 + CYCLE_OFFSET, axis_id=axis_id, measured_at=w, temperature_c=t,
            utility_day=float(k) / 1440, backlash_mean_um=float(bb), backlash_min_um=float(bb) - 5,
            backlash_max_um=float(bb) + 5, backlash_std_um=2.0, useful_travel_start_mm=0.0,
            useful_travel_end_mm=500.0, n_samples=1000, peak_speed_mm_min=3000.0) for k, w, t, bb in zip(i, when, tc, b)])
        c.execute(insert(LeadCriteriaRow), [dict(result_id=int(k) + 1, direction=d, e_p_um=1.0,
                                                 e_p_um_per_1000mm=8.0 + 0.01 * float(k % 7), v_u_um=12.0, v_300_um=6.0,
                                                 v_2pi_um=3.0, n_strokes=1) for k in i for d in ("positive", "negative")])  # fmt: skip
        c.execute(insert(TbeRow), [dict(result_id=int(k) + 1, task_name="circle", profile="circle", radius_mm=200.0,
                                        feed_mm_min=200.0, gain_per_s=10.0, tolerance_um=45.0, tbe_um=0.19 * float(bb),
                                        state="OK") for k, bb in zip(i, b)])  # fmt: skip
        if engine.dialect.name == "postgresql":  # explicit ids: move the sequences past them
            for table in ("cycles", "results", "lead_criteria"):
                c.execute(text(f"SELECT setval(pg_get_serial_sequence('{table}', 'id'), (SELECT max(id) FROM {table}))"))


@pytest.fixture
def loaded(engine):
    factory = make_session_factory(engine)
    with session_scope(factory) as s:
        m = config_repo.create_machine(s, "vmc", "rollup test")
        axis_id = config_repo.create_axis(s, m.id, f.settings()).id
    i, temp, b = _history()
    bulk_load_results(engine, axis_id, i, temp, b)
    with session_scope(factory) as s:
        hours = rollup.rebuild(s, axis_id)
    return factory, axis_id, (i, temp, b), hours


def test_a_long_trend_from_rollups_equals_the_statistics_of_every_row(loaded):
    factory, axis_id, (i, temp, b), hours = loaded
    assert hours == N // 60  # one rollup per hour of one-minute results
    with session_scope(factory) as s:
        v = results_repo.trend(s, axis_id, max_points=100)
    keep = np.isfinite(temp)
    assert v.points_total == N
    assert len(v.series.measurement_id) <= 100
    assert SPIKE + 1 + CYCLE_OFFSET in v.series.measurement_id and max(v.series.backlash_mean_um) == 300.0
    assert list(v.series.measured_at) == sorted(v.series.measured_at)
    st = v.stats["temperature_c"]["backlash_mean_um"]
    assert st.n == int(keep.sum())
    assert st.pearson_r() == pytest.approx(pearson_r(temp[keep], b[keep]), abs=1e-9)
    m_rows = TemperatureModel().fit(temp[keep], b[keep])
    m_sums = TemperatureModel().fit_sums(st)
    assert m_sums.beta_um_per_k_ == pytest.approx(m_rows.beta_um_per_k_, rel=1e-9)
    assert m_sums.backlash_ref_um_ == pytest.approx(m_rows.backlash_ref_um_, rel=1e-9)
    assert v.stats["utility_day"]["backlash_mean_um"].n == N
    assert v.stats["utility_day"]["v_u_um"].pearson_r() is None  # a constant criterion has no r


def test_the_tbe_history_of_a_long_range_keeps_the_extremes_of_the_screen_points(loaded):
    factory, axis_id, (i, temp, b), _ = loaded
    with session_scope(factory) as s:
        full = results_repo.tbe_history(s, axis_id)
        thin = results_repo.tbe_history(s, axis_id, max_points=100)
        shown = results_repo.trend(s, axis_id, max_points=100).series
    assert len(full) == N and len(thin) == len(shown.measurement_id) <= 100
    assert [t for t, *_ in thin] == list(shown.measured_at)
    assert max(v for _, _, v, _ in thin) == max(v for _, _, v, _ in full) == pytest.approx(0.19 * 300.0)
    assert min(v for _, _, v, _ in thin) == min(v for _, _, v, _ in full)


def test_a_range_that_cuts_hours_reads_their_rows_and_counts_every_measurement(loaded):
    factory, axis_id, (i, temp, b), _ = loaded
    since, until = T0 + timedelta(hours=5, minutes=17), T0 + timedelta(hours=50, minutes=41)
    inside = (i >= 5 * 60 + 17) & (i <= 50 * 60 + 41)
    with session_scope(factory) as s:
        v = results_repo.trend(s, axis_id, since=since, until=until, max_points=40)
        raw = results_repo.trend(s, axis_id, since=since, until=until)  # every row
    assert v.points_total == int(inside.sum()) == len(raw.series.measurement_id)
    assert all(since <= t <= until for t in v.series.measured_at)
    keep = inside & np.isfinite(temp)
    assert v.stats["temperature_c"]["backlash_mean_um"].pearson_r() == pytest.approx(
        pearson_r(temp[keep], b[keep]), abs=1e-9)
    assert v.stats["temperature_c"]["backlash_mean_um"].to_list() == pytest.approx(
        raw.stats["temperature_c"]["backlash_mean_um"].to_list(), rel=1e-9)


def test_each_stored_result_updates_its_hour(loaded):
    factory, axis_id, _, _ = loaded
    when = T0 + timedelta(hours=10, minutes=20, seconds=10)
    with session_scope(factory) as s:
        results_repo.save_finished_cycle(s, f.finished(axis_id, 400.0, when=when, temperature_c=21.0))
    with session_scope(factory) as s:
        row = s.scalar(select(TrendRollup).where(TrendRollup.axis_id == axis_id,
                                                 TrendRollup.bucket_start == rollup.hour_of(when)))  # fmt: skip
        n_rows = s.scalar(select(func.count()).select_from(Result).where(
            Result.axis_id == axis_id, Result.measured_at >= rollup.hour_of(when),
            Result.measured_at < rollup.hour_of(when) + rollup.HOUR))  # fmt: skip
        v = results_repo.trend(s, axis_id, max_points=100)
    assert row.n == n_rows == 61 and row.b_max_um == pytest.approx(400.0, abs=1.0)
    assert v.points_total == N + 1 and max(v.series.backlash_mean_um) == row.b_max_um


@pytest.mark.parametrize("backend", BACKENDS)
def test_the_migration_builds_rollups_for_results_stored_before_it(backend, tmp_path):
    from storage.db import make_engine

    url, handle = make_database(backend, tmp_path)
    engine = make_engine(url)
    upgrade(engine, "0003")
    factory = make_session_factory(engine)
    # the machine and axis as 0003 stored them: columns a later revision adds (0005's
    # worst_case_temperature_c) are not there yet, so the ORM's create_axis cannot write them
    now = T0
    with engine.begin() as c:
        machine_id = c.execute(insert(Machine).values(name="old", description="stored before 0004",
                                                      created_at=now)).inserted_primary_key[0]
        axis_id = c.execute(insert(Axis).values(
            machine_id=machine_id, name="y", transmission_mm_per_rev=6.857, screw_lead_mm=16.0,
            position_gain_per_s=10.0, travel_start_mm=0.0, travel_end_mm=500.0, controller_url="sim",
            measure_feed_mm_min=2000.0, measure_acceleration_mm_s2=500.0, warning_fraction=0.9,
            schedule_enabled=True, in_service_since=now, created_at=now)).inserted_primary_key[0]
    i, temp, b = _history(300, seed=1)
    bulk_load_results(engine, axis_id, i, temp, b)
    upgrade(engine)
    with session_scope(factory) as s:
        n = s.scalar(select(func.sum(TrendRollup.n)).where(TrendRollup.axis_id == axis_id))
        v = results_repo.trend(s, axis_id, max_points=4)
    engine.dispose()
    if handle is not None:
        handle.drop()
    assert n == 300 and v.points_total == 300


def test_history_rows_are_bounded_by_a_regular_thinning_that_keeps_the_newest(loaded):
    # the robust prognosis fit needs rows, not sums; a long history is thinned
    factory, axis_id, (i, temp, b), _ = loaded
    with session_scope(factory) as s:
        rows = results_repo.history_rows(s, axis_id, max_rows=1000)
        every = results_repo.history_rows(s, axis_id, max_rows=10_000)
    n_temp = int(np.isfinite(temp).sum())
    assert int(rows["total"]) == n_temp and every["backlash_mean_um"].size == n_temp
    assert 500 < rows["backlash_mean_um"].size <= 1000  # every ceil(n / 1000)-th row
    assert rows["measured_at_s"][-1] == every["measured_at_s"][-1]  # the newest is kept
    assert np.all(np.diff(rows["measured_at_s"]) > 0)
    assert np.ptp(rows["temperature_c"]) > 0.9 * np.ptp(every["temperature_c"])
