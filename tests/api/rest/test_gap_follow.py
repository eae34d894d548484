"""A caller follows its gap diagnosis by job id (the 202's ``Location``): a run stored
while it computes neither orphans the job nor hides its answer, the answer names the runs
it used and how many were stored since, and a job the service no longer knows is a 404
that says what to do. The diagnosis is a stand-in computed on the service's thread, held
by an Event, so each state is seen deterministically."""

from __future__ import annotations

import threading
from dataclasses import replace
from pathlib import Path

import pytest

from api.rest.routers import gap
from api.service.gap_jobs import dataset_of
from storage.dataset import append_runs, read_dataset
from tests.api.rest.conftest import hdr
from tests.api.rest.test_gap import store_case


@pytest.fixture
def held(app_env, monkeypatch):
    """The service's gap jobs computed in-process by a stand-in that waits for ``release``."""
    _client, svc, _keys, _axis_id = app_env
    monkeypatch.setattr(gap, "WAIT_S", 0.05)
    release = threading.Event()

    def stand_in(folder: str, plan: dict) -> dict:
        assert release.wait(60)
        used = [r.spec.file for r in dataset_of(Path(folder), plan["files"]).runs]
        return {"format": "mebm-gap/1", "effect": "cyclic_error", "runs_used": used,
                "computed_at": "2026-12-03T12:00:00+00:00"}

    monkeypatch.setattr(svc.gap_jobs, "compute", stand_in)
    monkeypatch.setattr(svc.gap_jobs, "use_process", False)
    yield release
    release.set()


def _store_one_more(svc, folder: Path, name: str) -> None:
    ds = read_dataset(folder)
    run = ds.runs[-1]
    append_runs(folder, ds.machine, [type(run)(replace(run.spec, file=name), run.columns)])


def test_the_job_is_followed_by_its_location_whatever_is_stored_meanwhile(app_env, held):
    client, svc, keys, axis_id = app_env
    case = store_case(svc, axis_id, "cyclic_error", seed=11)
    files = [r.spec.file for r in case.dataset.runs]
    first = client.get(f"/api/v1/axes/{axis_id}/gap", headers=hdr(keys["read"]))
    assert first.status_code == 202
    body, location = first.json(), first.headers["Location"]
    job = body["job"]
    assert location == f"/api/v1/axes/{axis_id}/gap/jobs/{job['id']}"
    assert job["state"] in ("queued", "running") and job["runs"] == len(files) and job["expected_s"] > 0
    assert f"job {job['id']}" in body["detail"] and "call " + location in body["detail"]
    folder = svc.executor.dataset_folder(next(iter(svc.executor._axes.values())))
    _store_one_more(svc, folder, "rt_late.csv")  # the next scheduled measurement, while it computes
    again = client.get(f"/api/v1/axes/{axis_id}/gap", headers=hdr(keys["read"]))
    assert again.status_code == 202 and again.json()["job"]["id"] == job["id"]  # the same job, not a new one
    assert len(svc.gap_jobs.pending_keys()) == 1
    held.set()
    svc.gap_jobs.job(job["id"]).future.result(timeout=60)
    done = client.get(location, headers=hdr(keys["read"]))
    assert done.status_code == 200
    d = done.json()
    assert d["job_id"] == job["id"] and d["effect"] == "cyclic_error"
    # it used the runs it was created with (the count shown while it waited), and says one came after
    assert d["runs_used"] == files[-16:] and len(d["runs_used"]) == job["runs"] and d["runs_stored_since"] == 1


def test_a_job_the_service_does_not_know_is_a_404_that_says_what_to_do(app_env, held):
    client, svc, keys, axis_id = app_env
    store_case(svc, axis_id, "cyclic_error", seed=11)
    r = client.get(f"/api/v1/axes/{axis_id}/gap/jobs/999", headers=hdr(keys["read"]))
    assert r.status_code == 404
    assert f"GET /api/v1/axes/{axis_id}/gap starts a new one" in r.json()["detail"]


def test_a_full_queue_says_when_to_ask_again(app_env, held):
    client, svc, keys, axis_id = app_env
    store_case(svc, axis_id, "cyclic_error", seed=11)
    bound = svc.gap_jobs.max_pending
    assert (bound, svc.gap_jobs.timeout_s) == (svc.settings.limits.gap_diagnoses_pending,
                                               svc.settings.limits.gap_diagnosis_timeout_s)
    codes = [client.get(f"/api/v1/axes/{axis_id}/gap", params={"runs": n}, headers=hdr(keys["read"]))
             for n in range(2, 3 + bound)]
    assert [r.status_code for r in codes] == [202] * bound + [429]
    refused = codes[-1]
    assert int(refused.headers["Retry-After"]) >= 1
    assert "start this one again then" in refused.json()["detail"]
    # the jobs wait in order: the second has the first ahead of it (or runs, once the first is held)
    places = [client.get(r.headers["Location"], headers=hdr(keys["read"])).json()["job"] for r in codes[:bound]]
    assert [p["id"] for p in places] == sorted(p["id"] for p in places)
    assert places[-1]["state"] == "queued" and places[-1]["ahead"] >= 1
