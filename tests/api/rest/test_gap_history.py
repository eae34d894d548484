"""The gap diagnosis of an axis' stored history respects the machine's history: runs on
both sides of a recorded repair are never pooled as one machine (the job uses the runs
since the last repair, says so, and shows that count while it waits), and each run goes
to the diagnosis with its utility day and temperature, so wear alone is not read as an
effect. Real diagnoses on few short round trips (seconds each)."""

from __future__ import annotations

import threading
from datetime import datetime, timedelta, timezone

import numpy as np
import pytest

from api.rest.routers import gap
from api.service.gap_jobs import dataset_of
from core.dataset import Dataset, MachineSpec
from core.sim import AxisModel, Effects, round_trip, simulate
from storage.dataset import write_dataset
from storage.db import config_repo, maintenance_repo, session_scope
from tests.api.rest.conftest import hdr
from tests.api.rest.test_gap import get_report

T0 = datetime(2026, 11, 2, 6, 0, tzinfo=timezone.utc)
STROKE_MM = 40.0  # short round trips: a few hundred samples each


def history(svc, axis_id, backlash_um: list[float], temperature_c: list[float], day_step: float = 1.0,
            seed: int = 3) -> list[str]:
    """Store one round trip per entry, a day apart, as the service stores them (measured_at,
    utility_day, temperature); returns the run files in measurement order."""
    with session_scope(svc.factory) as s:
        axis = config_repo.get_axis(s, axis_id)
    spec = axis.settings.spec
    rng = np.random.default_rng(seed)
    runs = []
    for i, (b, t) in enumerate(zip(backlash_um, temperature_c, strict=True)):
        model = AxisModel.from_axis_spec(spec, b, effects=Effects())
        program = round_trip(spec.travel_mm[0] + 3.0, spec.travel_mm[0] + 3.0 + STROKE_MM,
                             axis.settings.measure_feed_mm_min, axis.settings.measure_acceleration_mm_s2, dwell_s=0.2)
        trace = simulate({spec.name: model}, program, temperature_c=t, rate_hz=400.0, rng=rng)
        at = T0 + timedelta(days=day_step * i)
        runs.append(trace.to_run(f"rt_{spec.name}_{at:%Y%m%dT%H%M%S}.csv", utility_day=day_step * i,
                                 extra={"measured_at": at.isoformat(), "temperature_measured": True,
                                        "axis_id": axis_id}))
    write_dataset(svc.executor.dataset_folder(axis), Dataset(MachineSpec("vmc-850", {spec.name: spec}), tuple(runs)))
    return [r.spec.file for r in runs]


def repair(svc, axis_id, at: datetime, kind: str = "nut_replaced") -> None:
    with session_scope(svc.factory) as s:
        maintenance_repo.record_repair(s, axis_id, kind, by="test", performed_at=at)


@pytest.fixture
def diagnosing(app_env, monkeypatch):
    """The real diagnosis, computed in the service's process (no worker to spawn), with
    the queue held until the test lets it go, so the waiting job can be looked at."""
    _client, svc, _keys, _axis_id = app_env
    monkeypatch.setattr(gap, "WAIT_S", 0.05)
    monkeypatch.setattr(svc.gap_jobs, "use_process", False)
    go = threading.Event()
    svc.gap_jobs.hold(lambda: go.wait(120))
    yield go
    go.set()


def test_a_history_with_a_repair_in_the_middle_is_diagnosed_on_the_runs_after_it_and_says_so(app_env, diagnosing):
    client, svc, keys, axis_id = app_env
    # worn (247 µm and growing), the nut replaced, then 196 µm: two machines, not one
    files = history(svc, axis_id, [247.0, 249.0, 251.0, 253.0, 196.0, 196.5, 197.0],
                    [21.0, 20.0, 22.0, 21.0, 20.5, 21.5, 20.0])
    repair(svc, axis_id, T0 + timedelta(days=3, hours=12))
    after = files[4:]
    url = f"/api/v1/axes/{axis_id}/gap"
    queued = client.get(url, headers=hdr(keys["read"]))
    assert queued.status_code == 202, queued.text
    job = queued.json()["job"]
    assert job["state"] == "queued" and job["runs"] == len(after) == 3  # not the 16 asked for, nor the 7 stored
    period = job["period"]
    assert period["after_repair"]["kind"] == "nut_replaced" and period["runs_before_repair_left_out"] == 4
    assert (period["first_utility_day"], period["last_utility_day"]) == (4.0, 6.0)
    assert f"({len(after)} runs)" in queued.json()["detail"]
    diagnosing.set()
    r = get_report(client, url, hdr(keys["read"]))
    assert r.status_code == 200, r.text
    body = r.json()
    assert body["runs_used"] == after and len(body["runs_used"]) == job["runs"]
    assert body["period"]["first_run_at"] == (T0 + timedelta(days=4)).isoformat()
    assert body["period"]["last_run_at"] == (T0 + timedelta(days=6)).isoformat()
    assert body["period"]["repairs_within"] == []
    assert body["report"].startswith("Runs used: 3 stored run(s), measured 2026-11-06 06:00 UTC to 2026-11-08 06:00 UTC "
                                     "(utility days 4.00 to 6.00).")
    assert "after the last recorded repair (nut_replaced, 2026-11-05 18:00 UTC)" in body["report"]
    assert "4 run(s) before it left out" in body["report"]


def test_the_runs_of_a_diagnosis_carry_their_utility_day_and_temperature(app_env):
    _client, svc, _keys, axis_id = app_env
    files = history(svc, axis_id, [200.0, 201.0, 202.0], [19.5, 22.0, 20.5], day_step=0.25)
    with session_scope(svc.factory) as s:
        folder = svc.executor.dataset_folder(config_repo.get_axis(s, axis_id))
    ds = dataset_of(folder, files[1:])
    assert [r.spec.file for r in ds.runs] == files[1:]
    assert [r.spec.utility_day for r in ds.runs] == [0.25, 0.5]
    assert [r.spec.temperature_c for r in ds.runs] == [22.0, 20.5]


def test_fewer_than_two_runs_since_the_last_repair_are_not_pooled_with_older_ones(app_env):
    client, svc, keys, axis_id = app_env
    history(svc, axis_id, [240.0, 242.0, 244.0, 190.0], [21.0, 21.0, 21.0, 21.0])
    repair(svc, axis_id, T0 + timedelta(days=2, hours=12), kind="preload_adjusted")
    r = client.get(f"/api/v1/axes/{axis_id}/gap", headers=hdr(keys["read"]))
    assert r.status_code == 422, r.text
    detail = r.json()["detail"]
    assert "1 stored run(s) since the last recorded repair of the axis (preload_adjusted" in detail
    assert "not pooled" in detail and "Measure the axis again" in detail
    assert svc.gap_jobs.pending_keys() == []


# The wear is the nominal model's: its backlash grows linearly with the runs' utility day
# (fitted on the train runs, core.gap). Without it this history, 50 µm of wear while the
# shop warms by 3.5 K, is answered "thermal" (14.9 -> 0.8 µm); with it the answer is "none".
def test_a_history_of_pure_wear_is_answered_none(app_env, monkeypatch):
    client, svc, keys, axis_id = app_env
    monkeypatch.setattr(svc.gap_jobs, "use_process", False)
    # 10 µm per utility day and nothing else; the temperature rises over the days, not in step with them
    history(svc, axis_id, [200.0 + 10.0 * i for i in range(6)], [20.0, 21.5, 21.0, 22.5, 22.0, 23.5])
    r = get_report(client, f"/api/v1/axes/{axis_id}/gap", hdr(keys["read"]))
    assert r.status_code == 200, r.text
    assert r.json()["effect"] == "none", r.json()["report"]


def test_the_gap_page_shows_the_runs_after_the_repair_before_and_while_the_job_waits(tmp_path, monkeypatch):
    import re
    from html import unescape

    from fastapi.testclient import TestClient

    from api.rest import create_app
    from tests.api.rest.conftest import FakeRunner, make_settings
    from tests.api.ui.test_maintenance_forms import sign_in

    app = create_app(make_settings(f"sqlite:///{tmp_path}/g.sqlite3", tmp_path), runner=FakeRunner())
    with TestClient(app) as c:
        svc = app.state.service
        with session_scope(svc.factory) as s:
            key = config_repo.create_key(s, "ui-read", "read")[1]
            axis_id = config_repo.list_axes(s)[0].id
        used = []
        monkeypatch.setattr(svc.gap_jobs, "use_process", False)
        monkeypatch.setattr(svc.gap_jobs, "compute", lambda folder, plan: used.append(plan["files"]) or {
            "effect": "none", "gap_before_um": 1.0, "gap_after_um": 1.0, "noise_floor_um": 0.5, "candidates": [],
            "runs_used": plan["files"], "period": plan["period"], "report": plan["text"],
            "computed_at": "2026-12-03T12:00:00+00:00", "residuals": []})
        files = history(svc, axis_id, [247.0, 249.0, 251.0, 196.0, 196.5], [21.0, 20.0, 22.0, 20.5, 21.5])
        repair(svc, axis_id, T0 + timedelta(days=2, hours=12))
        csrf = sign_in(c, key)
        page = unescape(c.get(f"/ui/axes/{axis_id}/gap").text)
        assert re.search(r"about \d+ (s|min) for 2 runs", page)
        assert ("Next diagnosis: Runs used: 2 stored run(s), measured 2026-11-05 06:00 UTC to 2026-11-06 06:00 UTC"
                in page)
        assert "after the last recorded repair (nut_replaced, 2026-11-04 18:00 UTC)" in page
        assert "3 run(s) before it left out" in page
        go = threading.Event()
        svc.gap_jobs.hold(lambda: go.wait(60))
        try:
            started = c.post(f"/ui/axes/{axis_id}/gap", data={"csrf": csrf})
            waiting = unescape(started.text)
            assert "Waiting in the queue (job" in waiting and "2 runs):" in waiting
            assert "2 runs, measured 2026-11-05 06:00 UTC" in waiting and "3 runs before it left out" in waiting
        finally:
            go.set()
        job_id = int(re.search(r"gap\?job=(\d+)", str(started.url))[1])
        svc.gap_jobs.job(job_id).future.result(timeout=60)
        assert used == [files[3:]]  # the runs shown, and no others
