"""The service's gap jobs (api/service/gap_jobs.py): computed in a worker process, so a
diagnosis never holds the service's interpreter lock; a worker that dies fails its job
with a clear error and is replaced; a crash is not cached as an answer."""

from __future__ import annotations

import os
import threading
import time

import pytest

from api.service.gap_jobs import WORKER_NICE, DiagnosisCrashed, GapJobs, TooManyJobs


def where_am_i(folder: str, runs: int) -> dict:
    """A stand-in for the diagnosis (module level: the spawned worker imports it). runs=99
    dies the way an out-of-memory kill does: the process ends without an answer."""
    if runs == 99:
        os._exit(137)
    if runs == 98:  # a diagnosis that never ends by itself: marks that it runs, then takes an hour
        open(os.path.join(folder, "running"), "w").close()  # noqa: SIM115
        time.sleep(3600)
    return {"pid": os.getpid(), "folder": folder, "runs": runs, "nice": os.nice(0)}


@pytest.fixture
def jobs():
    j = GapJobs(compute=where_am_i)
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


def test_closing_ends_a_running_diagnosis_at_once_without_counting_a_crash(tmp_path):
    """The stop does not wait for a diagnosis (it is asked again), and leaves no process."""
    j = GapJobs(compute=where_am_i)
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
        f"sys.path[:0] = [{str(Path(__file__).resolve().parents[3])!r}, {str(Path(__file__).parent)!r}]\n"
        "from api.service.gap_jobs import GapJobs\n"
        "from test_gap_jobs import where_am_i\n"
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
    for _ in range(300):  # the watchdog looks every PARENT_POLL_S; wait up to 30 s
        if not Path(f"/proc/{worker}").exists() or Path(f"/proc/{worker}/stat").read_text().split()[2] == "Z":
            break
        time.sleep(0.1)
    else:
        raise AssertionError(f"the diagnosis process {worker} outlived its killed service")
