"""GET /axes/{id}/gap has bounded work: few jobs at once (429 beyond), abandoned jobs
are dropped, a cached answer does not read the runs again. The job queue is held busy
with a real job (an Event) so the bounds are seen deterministically."""

from __future__ import annotations

import threading

import pytest

from api.rest.routers import gap
from api.service.gap_jobs import JobAbandoned
from tests.api.rest.conftest import hdr
from tests.api.rest.test_gap import _store_case, get_report


@pytest.fixture
def busy_queue(app_env, monkeypatch):
    _client, svc, _keys, _axis_id = app_env
    monkeypatch.setattr(gap, "WAIT_S", 0.05)
    release = threading.Event()
    started = threading.Event()

    def hold():
        started.set()
        release.wait(60)

    svc.gap_jobs.hold(hold)
    assert started.wait(30)
    yield release
    release.set()


def test_more_pending_diagnoses_than_the_bound_are_refused_with_retry_after(app_env, busy_queue):
    client, svc, keys, axis_id = app_env
    _store_case(svc, axis_id, "cyclic_error", seed=11)
    bound = svc.gap_jobs.max_pending
    codes = [client.get(f"/api/v1/axes/{axis_id}/gap", params={"runs": n}, headers=hdr(keys["read"]))
             for n in range(2, 2 + bound + 3)]
    assert [r.status_code for r in codes[:bound]] == [202] * bound
    assert all(r.status_code == 429 and int(r.headers["Retry-After"]) > 0 for r in codes[bound:])
    again = client.get(f"/api/v1/axes/{axis_id}/gap", params={"runs": 2}, headers=hdr(keys["read"]))
    assert again.status_code == 202  # asking again for a pending one is not refused


def test_a_job_nobody_asks_for_any_more_is_dropped_before_it_starts(app_env, busy_queue):
    client, svc, keys, axis_id = app_env
    _store_case(svc, axis_id, "cyclic_error", seed=11)
    svc.gap_jobs.abandon_s = 0.0
    url = f"/api/v1/axes/{axis_id}/gap"
    assert client.get(url, params={"runs": 3}, headers=hdr(keys["read"])).status_code == 202
    (key,) = svc.gap_jobs.pending_keys()
    fut = svc.gap_jobs.future(key)
    busy_queue.set()
    with pytest.raises(JobAbandoned):
        fut.result(timeout=60)
    assert key not in svc.gap_jobs.pending_keys()  # the next request computes it anew


def test_a_cached_answer_does_not_read_the_runs_again(app_env):
    client, svc, keys, axis_id = app_env
    case = _store_case(svc, axis_id, "cyclic_error", seed=11)
    url = f"/api/v1/axes/{axis_id}/gap"
    first = get_report(client, url, hdr(keys["read"]))
    assert first.status_code == 200
    folder = svc.executor.dataset_folder(next(iter(svc.executor._axes.values())))
    for run in case.dataset.runs:  # damage every run; dataset.json (the data version) is unchanged
        (folder / run.spec.file).write_text("time_s\n0\n")
    again = client.get(url, headers=hdr(keys["read"]))
    assert again.status_code == 200
    a, f = again.json(), first.json()
    assert a.pop("age_s") >= f.pop("age_s") >= 0  # a cached answer says how old it is
    assert a == f
