"""The service layer: schedules, the per-axis queue, failures, database outages."""

from __future__ import annotations

import json
import threading
from dataclasses import replace
from datetime import datetime, timedelta, timezone

import pytest

from api.service.cycles.scheduler import missed_since
from api.service.service import Service
from storage.db import (
    Schedule,
    WaitingCycleError,
    config_repo,
    integrity_problems,
    make_engine,
    make_session_factory,
    results_repo,
    session_scope,
)
from tests.api.rest.conftest import FakeRunner, make_settings
from tests.storage.db import factories as f
from tests.waiting import poll


@pytest.fixture
def service(engine, db_url, tmp_path):
    runner = FakeRunner()
    svc = Service(make_settings(db_url, tmp_path), runner=runner)
    svc.start()
    svc.test_runner = runner
    with session_scope(svc.factory) as s:
        svc.test_axis = config_repo.list_axes(s)[0]
    yield svc
    if svc.test_runner.gate is not None:
        svc.test_runner.gate.set()
    svc.stop()


def cycles(svc, **kw):
    with session_scope(svc.factory) as s:
        return results_repo.list_measurements(s, svc.test_axis.id, limit=500, **kw)[1]


def test_missed_run_rule():
    now = datetime(2026, 6, 1, 12, 0, tzinfo=timezone.utc)
    every_hour = Schedule(interval_s=3600)
    assert missed_since(every_hour, now - timedelta(hours=5), now)
    assert not missed_since(every_hour, now - timedelta(minutes=30), now)
    daily = Schedule(cron="0 6 * * *")
    assert missed_since(daily, now - timedelta(days=3), now)
    assert not missed_since(daily, now - timedelta(hours=5), now)  # 07:00 -> next 06:00 is tomorrow
    assert not missed_since(every_hour, None, now)


def test_interval_schedule_runs_and_a_failure_does_not_stop_it(service):
    svc, runner = service, service.test_runner
    runner.fail = "ControllerConnectionError: connection refused"
    with session_scope(svc.factory) as s:
        axis = config_repo.set_schedule(s, svc.test_axis.id, Schedule(interval_s=1.0))
    svc.axis_changed(axis)
    assert poll(lambda: len(cycles(svc, status="failed")) >= 2)
    runner.fail = None
    assert poll(lambda: len(cycles(svc, status="ok")) >= 1)
    failed = cycles(svc, status="failed")[0]
    assert failed.trigger == "schedule" and "refused" in failed.failure_reason


def test_never_two_cycles_at_once_and_manual_queues_behind(service):
    svc, runner = service, service.test_runner
    runner.gate = threading.Event()
    active, peak = [0], [0]
    inner = svc.executor.runner

    def counting(axis, url):
        active[0] += 1
        peak[0] = max(peak[0], active[0])
        try:
            return inner(axis, url)
        finally:
            active[0] -= 1

    svc.executor.runner = counting
    first = svc.trigger(svc.test_axis.id, "op")
    assert runner.running.wait(5)
    second = svc.trigger(svc.test_axis.id, "op")
    with pytest.raises(WaitingCycleError) as refused:  # one waits already: not stacked
        svc.trigger(svc.test_axis.id, "op")
    assert refused.value.cycle.id == second.id != first.id
    assert svc.scheduler.request(svc.test_axis.id, "schedule") is not None
    assert svc.scheduler.request(svc.test_axis.id, "schedule") is None  # previous scheduled one still waits
    statuses = {c.id: c.status for c in cycles(svc)}
    assert statuses[first.id] == "running" and statuses[second.id] == "queued"
    runner.gate.set()
    assert svc.scheduler.idle(30)
    assert peak[0] == 1
    assert [c.status for c in cycles(svc)] == ["ok", "ok", "ok"]


def test_catch_up_runs_once_after_downtime(engine, db_url, tmp_path):
    runner = FakeRunner()
    settings = replace(make_settings(db_url, tmp_path), catch_up_missed=True)
    svc = Service(settings, runner=runner)
    svc.start()
    axis_id = svc.report and config_repo
    with session_scope(svc.factory) as s:
        axis_id = config_repo.list_axes(s)[0].id
        # the last scheduled cycle was 10 periods ago: the service was down
        results_repo.save_finished_cycle(
            s, replace(f.finished(axis_id, 100.0, when=datetime.now(timezone.utc) - timedelta(hours=10)),
                       trigger="schedule"))
    svc.stop()
    svc = Service(settings, runner=runner)
    svc.start()
    try:
        assert svc.scheduler.idle(30)
        with session_scope(svc.factory) as s:
            _, rows = results_repo.list_measurements(s, axis_id)
        assert [c.trigger for c in rows].count("catch_up") == 1
    finally:
        svc.stop()


def test_database_outage_keeps_the_cycle_on_disk_and_stores_it_later(service):
    svc, runner = service, service.test_runner
    real = svc.executor.factory
    down = make_engine("postgresql://nobody@127.0.0.1:1/none")
    svc.executor.factory = make_session_factory(down)
    runner.backlash_um = 250.0
    svc.scheduler.request(svc.test_axis.id, "schedule")
    assert svc.scheduler.idle(30)
    spooled = svc.executor.pending()
    assert len(spooled) == 1 and cycles(svc, status="ok") == []
    assert list((svc.executor.datasets_dir).glob("*/rt_y_*.csv"))  # the raw run is on disk
    svc.executor.factory = real
    assert svc.executor.replay_spool() == 1
    assert svc.executor.pending() == []
    (c,) = cycles(svc, status="ok")
    assert c.backlash_mean_um == pytest.approx(250.0, abs=3) and c.temperature_c == 20.0
    with session_scope(svc.factory) as s:
        assert results_repo.list_alerts(s, "active")[0] == 1  # the alert decision was replayed too
    assert svc.executor.replay_spool() == 0
    assert integrity_problems(svc.engine) == []
    down.dispose()


def test_api_answers_503_when_the_database_is_down(app_env):
    client, svc, keys, axis_id = app_env
    real = svc.factory
    svc.factory = make_session_factory(make_engine("postgresql://nobody@127.0.0.1:1/none"))
    svc.status.factory = svc.factory
    client.app.state.key_cache.clear()
    try:
        r = client.get("/api/v1/machines", headers={"X-API-Key": keys["read"]})
        assert r.status_code == 503 and "database" in r.json()["detail"]
        assert client.get("/healthz").status_code == 503
    finally:
        svc.factory = real
        svc.status.factory = real


def test_bootstrap_admin_key_once_and_demo_keys_kept(engine, db_url, tmp_path):
    runner = FakeRunner()
    secret = "bootstrap-" + "x" * 30
    settings = replace(make_settings(db_url, tmp_path), bootstrap_admin_key=secret, scheduler_enabled=False)
    svc = Service(settings, runner=runner)
    assert svc.start().bootstrap_admin == "bootstrap-admin"
    with session_scope(svc.factory) as s:
        assert config_repo.authenticate(s, secret).role == "admin"
    svc.stop()
    other = replace(settings, bootstrap_admin_key="another-" + "y" * 30)
    svc = Service(other, runner=runner)
    assert svc.start().bootstrap_admin is None  # an admin key exists: ignored
    svc.stop()
    # demo keys: created hashed at first start and shown then only (test_hygiene has the details)
    demo = replace(settings, bootstrap_admin_key=None, demo_keys=True,
                   axes=(replace(settings.axes[0], settings=replace(settings.axes[0].settings, controller_url="sim")),))
    first = Service(demo, runner=runner)
    keys = first.start().demo_keys
    first.stop()
    assert set(keys) == {"read", "operate", "admin"}
    assert (tmp_path / "demo-keys.json").stat().st_mode & 0o777 == 0o600
    again = Service(demo, runner=runner)
    assert again.start().demo_keys == {}
    with session_scope(again.factory) as s:
        assert config_repo.authenticate(s, keys["read"]).role == "read"
    again.stop()


def test_driver_runner_reports_an_unreachable_controller_as_a_failed_outcome():
    import socket

    from api.service.cycles.runner import DriverRunner
    from storage.db import AxisRecord

    with socket.socket() as s:  # a free port nobody listens on
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    axis = AxisRecord(1, 1, "m", f.settings())
    out = DriverRunner(timeout_s=0.5)(axis, f"modbus://127.0.0.1:{port}")
    assert not out.ok and out.round_trip is None
    assert "connection" in out.reason or "timeout" in out.reason
    bad = DriverRunner()(axis, "ftp://nowhere")
    assert not bad.ok and "scheme" in bad.reason


def _outage(svc):
    """Point the executor at an unreachable database; returns a function that ends the outage."""
    real = svc.executor.factory
    down = make_engine("postgresql://nobody@127.0.0.1:1/none")
    svc.executor.factory = make_session_factory(down)

    def restore():
        svc.executor.factory = real
        down.dispose()

    return restore


def _measure(svc):
    svc.scheduler.request(svc.test_axis.id, "schedule")
    assert svc.scheduler.idle(30)


def test_a_run_the_dataset_folder_refuses_is_kept_unfiled_and_stored_after_an_outage(service, tmp_path):
    svc, runner = service, service.test_runner
    blocked = tmp_path / "not-a-folder"
    blocked.write_text("a file where the datasets folder should be")
    svc.executor.datasets_dir = blocked
    restore = _outage(svc)
    runner.backlash_um = 230.0
    _measure(svc)
    (spooled,) = svc.executor.pending()
    assert list(svc.executor.unfiled_dir.glob("*.npz"))  # the trace is on disk, outside the folder
    restore()
    assert svc.executor.replay_spool() == 1
    (c,) = cycles(svc, status="ok")
    assert c.backlash_mean_um == pytest.approx(230.0, abs=3)
    assert svc.executor.pending() == []


def test_a_spool_file_without_its_run_is_recorded_as_failed_and_does_not_block_the_rest(service):
    svc, runner = service, service.test_runner
    restore = _outage(svc)
    _measure(svc)
    _measure(svc)
    first, second = svc.executor.pending()
    doc = json.loads(first.read_text())
    doc["dataset_folder"], doc["run_file"] = None, None  # as an older version could leave it
    first.write_text(json.dumps(doc))
    restore()
    assert svc.executor.replay_spool() == 2
    assert len(cycles(svc, status="ok")) == 1
    (failed,) = cycles(svc, status="failed")
    assert "raw run was not kept" in failed.failure_reason
    assert svc.executor.pending() == [] and not list(svc.executor.spool_dir.glob("*.bad"))


def test_replay_keeps_the_spool_file_while_the_axis_cannot_be_read(service):
    svc = service
    restore = _outage(svc)
    _measure(svc)
    svc.executor._axes.clear()  # a fresh start during the outage: no axis settings cached
    assert svc.executor.replay_spool() == 0
    assert len(svc.executor.pending()) == 1 and not list(svc.executor.spool_dir.glob("*.bad"))
    restore()
    assert svc.executor.replay_spool() == 1 and len(cycles(svc, status="ok")) == 1


def test_a_cycle_that_can_be_neither_spooled_nor_stored_is_kept_in_memory(service, tmp_path):
    svc = service
    blocked = tmp_path / "spool-blocked"
    blocked.write_text("a file where the spool folder should be")
    svc.executor.spool_dir = blocked
    restore = _outage(svc)
    _measure(svc)
    assert len(svc.executor.unsaved) == 1 and svc.executor.has_pending()
    restore()
    svc._retry_spool()
    assert svc.executor.unsaved == [] and len(cycles(svc, status="ok")) == 1


def test_replay_reads_only_its_own_run(service):
    svc = service
    _measure(svc)  # stored normally; its run is the first in the folder
    restore = _outage(svc)
    _measure(svc)
    (older,) = sorted(svc.executor.datasets_dir.glob("*/rt_y_*.csv"))[:1]
    older.write_text("time_s,y_motor_rev,y_table_mm\n0,1,oops\n")  # a damaged neighbour
    restore()
    assert svc.executor.replay_spool() == 1
    assert len(cycles(svc, status="ok")) == 2


def test_the_start_up_heap_is_collected_and_frozen_once_per_process(engine, db_url, tmp_path, monkeypatch):
    """The first service a process starts moves its start-up objects out of the collector's
    sight; a service started after it in the same process (as the tests do) finds them
    frozen already and does not pay a full collection of the heap again."""
    import gc

    gc.unfreeze()  # a process that has frozen nothing yet
    collections = []
    real_collect = gc.collect
    monkeypatch.setattr(gc, "collect", lambda *a: collections.append(a) or real_collect(*a))
    for i in range(2):
        svc = Service(make_settings(db_url, tmp_path / f"s{i}"), runner=FakeRunner())
        svc.start()
        assert gc.get_freeze_count() > 0
        svc.stop()
    assert len(collections) == 1
