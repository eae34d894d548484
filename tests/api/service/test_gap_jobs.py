"""The service's gap jobs (api/service/gap_jobs.py): computed in a worker process, so a
diagnosis never holds the service's interpreter lock; a worker that dies fails its job
with a clear error and is replaced; a crash is not cached as an answer."""

from __future__ import annotations

import os
import threading
import time

import pytest

from api.service.gap_jobs import FIRST_DIAGNOSIS_EXTRA_S, WORKER_NICE, DiagnosisCrashed, DiagnosisTimedOut, GapJobs, TooManyJobs
from tests.api.service.stand_in_diagnosis import where_am_i  # light: the spawned worker imports it
from tests.clock import ManualClock


@pytest.fixture
def jobs():
    j = GapJobs(compute=where_am_i)
    yield j
    j.close()


@pytest.fixture
def own_priority_jobs():
    """Jobs whose worker runs at the tests' own priority (``nice=0``): at the default +10
    the tests running beside it on a busy machine would starve it."""
    j = GapJobs(compute=where_am_i, nice=0)
    yield j
    j.close()


def test_the_diagnosis_runs_in_another_process_which_is_kept_for_the_next_job(jobs, tmp_path):
    first = jobs.submit(("a", 2), tmp_path, 2).result(timeout=120)
    second = jobs.submit(("a", 3), tmp_path, 3).result(timeout=120)
    assert first["pid"] != os.getpid()
    assert first["nice"] == min(os.nice(0) + WORKER_NICE, 19)  # below the service's priority
    assert second["pid"] == first["pid"]
    assert (first["runs"], second["runs"]) == (2, 3) and first["folder"] == str(tmp_path)
    assert jobs.submit(("a", 2), tmp_path, 2).result(timeout=1) == first  # the cached answer


def test_a_worker_that_dies_fails_its_job_and_is_replaced(own_priority_jobs, tmp_path):
    jobs = own_priority_jobs
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


def test_closing_ends_a_running_diagnosis_at_once_without_counting_a_crash(tmp_path):
    """The stop does not wait for a diagnosis (it is asked again), and leaves no process."""
    j = GapJobs(compute=where_am_i, nice=0)
    fut = j.submit(("c", 98), tmp_path, 98)
    deadline = time.monotonic() + 120
    while not (tmp_path / "running").exists() and time.monotonic() < deadline:
        time.sleep(0.05)
    procs = list(j._pool._processes.values())
    closing = threading.Thread(target=j.close)  # returns although the diagnosis wanted an hour
    closing.start()
    closing.join(120)
    assert not closing.is_alive()
    assert procs and not any(p.is_alive() for p in procs)
    with pytest.raises(DiagnosisCrashed, match="service stopped"):
        fut.result(timeout=10)
    assert j.crashes == 0


def test_the_pending_bound_holds_without_a_process(tmp_path):
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


def test_the_worker_ends_when_the_service_process_is_killed(tmp_path):
    """A service killed with SIGKILL leaves no diagnosis process behind."""
    import signal
    import subprocess
    import sys
    import time
    from pathlib import Path

    script = tmp_path / "svc.py"
    script.write_text(
        "import os, sys\n"
        f"sys.path[:0] = [{str(Path(__file__).resolve().parents[3])!r}]\n"
        "from api.service.gap_jobs import GapJobs\n"
        "from tests.api.service.stand_in_diagnosis import where_am_i\n"
        "if __name__ == '__main__':\n"
        "    j = GapJobs(compute=where_am_i)\n"
        "    print(j.submit(('k', 2), '.', 2).result(timeout=120)['pid'], flush=True)\n"
        "    import time; time.sleep(600)\n")
    svc = subprocess.Popen([sys.executable, str(script)], stdout=subprocess.PIPE, text=True)
    try:
        worker = int(svc.stdout.readline())
        assert Path(f"/proc/{worker}").exists()
    finally:
        svc.send_signal(signal.SIGKILL)
        svc.wait(30)
    for _ in range(300):  # the worker's watchdog sees its parent end; wait up to 30 s
        if not Path(f"/proc/{worker}").exists() or Path(f"/proc/{worker}/stat").read_text().split()[2] == "Z":
            break
        time.sleep(0.1)
    else:
        raise AssertionError(f"the diagnosis process {worker} outlived its killed service")


def test_one_pending_job_per_run_set_whatever_is_stored_meanwhile(tmp_path):
    """A run stored while a diagnosis waits (a new data version) joins the pending job
    instead of orphaning it: the page and the API follow the same job id, and the bound
    counts only jobs someone can still get an answer from."""
    release = threading.Event()
    j = GapJobs(compute=lambda folder, plan: (release.wait(60), {"runs": plan["requested"]})[1], use_process=False, max_pending=1)
    try:
        first = j.start(("f", 16), tmp_path, 16, version=(1, 100))
        again = j.start(("f", 16), tmp_path, 16, version=(2, 200))  # a run stored since
        assert again is first and j.pending_keys() == [("f", 16)]
        with pytest.raises(TooManyJobs) as refused:
            j.start(("g", 16), tmp_path, 16, version=(1, 100))
        assert "start this one again then" in str(refused.value) and refused.value.retry_after_s >= 1
        release.set()
        assert first.future.result(timeout=60) == {"runs": 16}
        assert j.job(first.id).state == "done"
        assert j.start(("f", 16), tmp_path, 16, version=(1, 100)) is first  # the answer kept for its version
        newer = j.start(("f", 16), tmp_path, 16, version=(2, 200))  # the newer runs: a new job
        assert newer.id != first.id and newer.future.result(timeout=60) == {"runs": 16}
        assert j.latest(("f", 16)) is newer
    finally:
        release.set()
        j.close()


def test_progress_says_the_place_in_the_queue_and_the_expected_time(tmp_path):
    clock = ManualClock(1000.0)
    go = {n: threading.Event() for n in (4, 8)}
    started = {n: threading.Event() for n in (4, 8)}

    def compute(folder, plan):
        runs = plan["requested"]
        started[runs].set()
        go[runs].wait(60)
        clock.t += 30.0 * runs / 4  # the diagnosis' duration, on the injected clock
        return {"runs": runs}

    j = GapJobs(compute=compute, use_process=False, clock=clock, max_pending=3)
    try:
        a = j.start(("f", 4), tmp_path, 4, size_bytes=2_000_000)
        b = j.start(("f", 8), tmp_path, 8, size_bytes=4_000_000)
        assert started[4].wait(60)
        clock.t += 10.0
        pa, pb = j.progress(a), j.progress(b)
        assert (pa["state"], pa["ahead"], pa["elapsed_s"]) == ("running", 0, 10.0)
        assert (pb["state"], pb["ahead"], pb["waited_s"]) == ("queued", 1, 10.0)
        assert pb["remaining_s"] == pytest.approx(pa["remaining_s"] + pb["expected_s"])
        assert pb["expected_s"] > pa["expected_s"]  # twice the runs' bytes
        go[4].set()
        a.future.result(timeout=60)
        assert started[8].wait(60)
        # the first diagnosis timed here sets the next ones' expected time: 40 s for 2 MB, less the compilation
        assert j.progress(a)["elapsed_s"] == 40.0 and "ahead" not in j.progress(a)
        assert j.expected_s(8, 4_000_000) == pytest.approx(2 * (40.0 - FIRST_DIAGNOSIS_EXTRA_S))
        go[8].set()
        assert b.future.result(timeout=60) == {"runs": 8}
    finally:
        for e in go.values():
            e.set()
        j.close()


def test_a_diagnosis_past_the_time_limit_is_stopped_and_says_what_to_do(tmp_path):
    j = GapJobs(compute=where_am_i, timeout_s=1.0)
    try:
        slow = j.start(("t", 98), tmp_path, 98, version=(1, 1))
        with pytest.raises(DiagnosisTimedOut, match="ran longer than 1 s and was stopped. Diagnose fewer runs"):
            slow.future.result(timeout=300)
        assert j.timeouts == 1 and slow.state == "failed"
        assert "limits.gap_diagnosis_timeout_s" in j.progress(slow)["detail"]
        # kept for its data version (a poller does not start it again and again) ...
        assert j.start(("t", 98), tmp_path, 98, version=(1, 1)) is slow
        # ... and the next diagnosis gets a fresh process (under a limit a spawn fits in on a loaded machine)
        j.timeout_s = 600.0
        assert j.submit(("t", 2), tmp_path, 2).result(timeout=120)["runs"] == 2
        again = j.start(("t", 98), tmp_path, 98, version=(1, 1), fresh=True)  # a start from the page: computed anew
        assert again is not slow and again.id > slow.id and again.state in ("queued", "running")
    finally:
        j.close()
