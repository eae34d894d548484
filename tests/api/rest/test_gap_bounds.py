"""GET /axes/{id}/gap has bounded work: few jobs at once (429 beyond), abandoned jobs
are dropped, a cached answer does not read the runs again. The single diagnosis worker
is held busy with a real job (an Event) so the bounds are seen deterministically."""

from __future__ import annotations

import threading

import pytest

from api.rest.routers import gap
from tests.api.rest.conftest import hdr
from tests.api.rest.test_gap import _store_case, get_report


@pytest.fixture(autouse=True)
def no_jobs_of_other_tests():
    """The job table is per process: start each test without another test's jobs (still
    queued ones find themselves dropped and end at once)."""
    with gap._lock:
        gap._jobs.clear()
    yield
    with gap._lock:
        gap._jobs.clear()


@pytest.fixture
def busy_worker(monkeypatch):
    monkeypatch.setattr(gap, "WAIT_S", 0.05)
    release = threading.Event()
    started = threading.Event()

    def hold():
        started.set()
        release.wait(60)

    gap._worker.submit(hold)
    assert started.wait(30)
    yield release
    release.set()


def test_more_pending_diagnoses_than_the_bound_are_refused_with_retry_after(app_env, busy_worker):
    client, svc, keys, axis_id = app_env
    _store_case(svc, axis_id, "cyclic_error", seed=11)
    codes = [client.get(f"/api/v1/axes/{axis_id}/gap", params={"runs": n}, headers=hdr(keys["read"]))
             for n in range(2, 2 + gap.MAX_PENDING + 3)]
    assert [r.status_code for r in codes[:gap.MAX_PENDING]] == [202] * gap.MAX_PENDING
    assert all(r.status_code == 429 and int(r.headers["Retry-After"]) > 0 for r in codes[gap.MAX_PENDING:])
    again = client.get(f"/api/v1/axes/{axis_id}/gap", params={"runs": 2}, headers=hdr(keys["read"]))
    assert again.status_code == 202  # asking again for a pending one is not refused


def test_a_job_nobody_asks_for_any_more_is_dropped_before_it_starts(app_env, busy_worker, monkeypatch):
    client, svc, keys, axis_id = app_env
    _store_case(svc, axis_id, "cyclic_error", seed=11)
    monkeypatch.setattr(gap, "ABANDON_S", 0.0)
    url = f"/api/v1/axes/{axis_id}/gap"
    assert client.get(url, params={"runs": 3}, headers=hdr(keys["read"])).status_code == 202
    (key,) = list(gap._jobs)
    fut = gap._jobs[key].future
    busy_worker.set()
    with pytest.raises(gap.JobAbandoned):
        fut.result(timeout=60)
    assert key not in gap._jobs  # the next request computes it anew


def test_a_cached_answer_does_not_read_the_runs_again(app_env, monkeypatch):
    client, svc, keys, axis_id = app_env
    case = _store_case(svc, axis_id, "cyclic_error", seed=11)
    url = f"/api/v1/axes/{axis_id}/gap"
    first = get_report(client, url, hdr(keys["read"]))
    assert first.status_code == 200
    folder = svc.executor.dataset_folder(next(iter(svc.executor._axes.values())))
    for run in case.dataset.runs:  # damage every run; dataset.json (the data version) is unchanged
        (folder / run.spec.file).write_text("time_s\n0\n")
    again = client.get(url, headers=hdr(keys["read"]))
    assert again.status_code == 200 and again.json() == first.json()
