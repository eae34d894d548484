"""GET /axes/{id}/gap has bounded work: few jobs at once (429 beyond), abandoned jobs
are dropped (that a cached answer does not read the runs again is in test_gap.py). The job
queue is held busy with a real job (an Event) so the bounds are seen deterministically."""

from __future__ import annotations

import threading

import pytest

from api.rest.routers import gap
from api.service.gap_jobs import JobAbandoned
from core.gap import GapError
from tests.api.rest.conftest import hdr
from tests.api.rest.test_gap import store_case


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
    store_case(svc, axis_id, "cyclic_error", seed=11)
    bound = svc.gap_jobs.max_pending
    codes = [client.get(f"/api/v1/axes/{axis_id}/gap", params={"runs": n}, headers=hdr(keys["read"]))
             for n in range(2, 2 + bound + 3)]
    assert [r.status_code for r in codes[:bound]] == [202] * bound
    assert all(r.status_code == 429 and int(r.headers["Retry-After"]) > 0 for r in codes[bound:])
    again = client.get(f"/api/v1/axes/{axis_id}/gap", params={"runs": 2}, headers=hdr(keys["read"]))
    assert again.status_code == 202  # asking again for a pending one is not refused


def test_a_job_nobody_asks_for_any_more_is_dropped_before_it_starts(app_env, busy_queue):
    client, svc, keys, axis_id = app_env
    store_case(svc, axis_id, "cyclic_error", seed=11)
    svc.gap_jobs.abandon_s = 0.0
    url = f"/api/v1/axes/{axis_id}/gap"
    assert client.get(url, params={"runs": 3}, headers=hdr(keys["read"])).status_code == 202
    (key,) = svc.gap_jobs.pending_keys()
    fut = svc.gap_jobs.future(key)
    busy_queue.set()
    with pytest.raises(JobAbandoned):
        fut.result(timeout=60)
    assert key not in svc.gap_jobs.pending_keys()  # the next request computes it anew


def test_waiting_gap_requests_hold_no_worker_thread(tmp_path, monkeypatch):
    """Sixty clients wait on one diagnosis that cannot start (the queue is held): all sixty
    wait at once, more than the server's 40 worker threads could hold, and ``/healthz`` (a
    threaded endpoint) is answered while they wait."""
    import asyncio

    import httpx

    from storage.db import config_repo, session_scope
    from tests.api.rest.conftest import ServedApp
    from tests.waiting import poll

    served = ServedApp(tmp_path)
    release = threading.Event()
    try:
        svc = served.app.state.service
        with session_scope(svc.factory) as s:
            key = config_repo.create_key(s, "mes", "read")[1]
            axis_id = config_repo.list_axes(s)[0].id
        store_case(svc, axis_id, "cyclic_error", seed=11)
        started = threading.Event()
        svc.gap_jobs.hold(lambda: (started.set(), release.wait(120)))
        assert started.wait(30)
        monkeypatch.setattr(gap, "WAIT_S", 60.0)  # the sixty wait until the test has seen them all
        svc.gap_jobs.use_process = False  # what the job then computes is not this test's matter: it ends at once
        monkeypatch.setattr(svc.gap_jobs, "compute", lambda folder, runs: (_ for _ in ()).throw(GapError("held")))

        async def go():
            limits = httpx.Limits(max_connections=100, max_keepalive_connections=100)
            async with httpx.AsyncClient(base_url=served.url, timeout=120, limits=limits) as c:
                waiting = [asyncio.create_task(c.get(f"/api/v1/axes/{axis_id}/gap", headers=hdr(key)))
                           for _ in range(60)]
                job = await asyncio.to_thread(poll, lambda: next(iter(svc.gap_jobs.pending_jobs()), None), 60)
                seen = await asyncio.to_thread(poll, lambda: job.waiting == 60, 60)
                health = await c.get("/healthz")
                still = job.waiting
                release.set()  # the held queue moves on: the job runs and the sixty are answered
                return seen, health.status_code, still, await asyncio.gather(*waiting)

        seen, health, still, answers = asyncio.run(go())
        assert seen and health in (200, 503) and still == 60
        assert [r.status_code for r in answers] == [422] * 60  # each got the job's own answer
    finally:
        release.set()
        served.close()
