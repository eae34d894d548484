"""The service's gap jobs (api/service/gap_jobs.py): computed in a worker process, so a
diagnosis never holds the service's interpreter lock; a worker that dies fails its job
with a clear error and is replaced; a crash is not cached as an answer."""

from __future__ import annotations

import os

import pytest

from api.service.gap_jobs import DiagnosisCrashed, GapJobs, TooManyJobs


def where_am_i(folder: str, runs: int) -> dict:
    """A stand-in for the diagnosis (module level: the spawned worker imports it). runs=99
    dies the way an out-of-memory kill does: the process ends without an answer."""
    if runs == 99:
        os._exit(137)
    return {"pid": os.getpid(), "folder": folder, "runs": runs}


@pytest.fixture
def jobs():
    j = GapJobs(compute=where_am_i)
    yield j
    j.close()


def test_the_diagnosis_runs_in_another_process_which_is_kept_for_the_next_job(jobs, tmp_path):
    first = jobs.submit(("a", 2), tmp_path, 2).result(timeout=120)
    second = jobs.submit(("a", 3), tmp_path, 3).result(timeout=120)
    assert first["pid"] != os.getpid()
    assert second["pid"] == first["pid"]
    assert (first["runs"], second["runs"]) == (2, 3) and first["folder"] == str(tmp_path)
    assert jobs.submit(("a", 2), tmp_path, 2).result(timeout=1) == first  # the cached answer


def test_a_worker_that_dies_fails_its_job_and_is_replaced(jobs, tmp_path):
    before = jobs.submit(("b", 2), tmp_path, 2).result(timeout=120)
    with pytest.raises(DiagnosisCrashed, match="died"):
        jobs.submit(("b", 99), tmp_path, 99).result(timeout=120)
    assert jobs.crashes == 1
    after = jobs.submit(("b", 3), tmp_path, 3).result(timeout=120)
    assert after["pid"] != before["pid"]  # a fresh process
    # the crash was not cached: asking again computes again (and dies again)
    with pytest.raises(DiagnosisCrashed):
        jobs.submit(("b", 99), tmp_path, 99).result(timeout=120)
    assert jobs.crashes == 2


def test_the_pending_bound_holds_without_a_process(tmp_path):
    import threading

    j = GapJobs(compute=where_am_i, use_process=False, max_pending=1)
    release = threading.Event()
    j.hold(lambda: release.wait(60))
    try:
        j.submit(("c", 2), tmp_path, 2)
        with pytest.raises(TooManyJobs):
            j.submit(("c", 3), tmp_path, 3)
        release.set()
        assert j.submit(("c", 2), tmp_path, 2).result(timeout=60)["pid"] == os.getpid()
    finally:
        release.set()
        j.close()
