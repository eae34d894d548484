"""Cycles in worker processes (api.service.cycles.runner.CycleProcesses): the acquisition and the
analysis run off the service's interpreter; a busy or starting pool never delays a cycle;
a process that dies fails its cycle with a reason and the next one runs in a fresh process."""

from __future__ import annotations

import logging
import multiprocessing
import os
import signal
import threading
import time
from dataclasses import replace

import pytest

from api.service.config.loading import parse_settings
from api.service.config.settings import ConfigError, default_settings
from api.service.cycles.runner import CycleProcessDied, CycleProcesses, DriverRunner, NoFreeProcess
from api.service.service import Service
from api.service.worker_process import end_pool, spawn_pool, still_running, wait_for_sentinels
from storage.db import AxisRecord, config_repo, results_repo, session_scope
from tests.api.rest.conftest import make_settings
from tests.waiting import poll
from tests.storage.db import factories as f


def started(processes: CycleProcesses) -> bool:
    return processes._free == processes.processes


def _pid() -> int:
    return os.getpid()


def _wait_for_file(path: str) -> None:
    """Runs in the worker process until the test creates ``path``: a call the test holds."""
    while not os.path.exists(path):
        time.sleep(0.01)


def test_a_free_process_runs_the_call_a_busy_one_sends_it_back_at_once(tmp_path):
    procs = CycleProcesses(1)
    procs.start()
    release = tmp_path / "release"
    try:
        assert poll(lambda: started(procs), 60)
        assert procs.run(_pid) != os.getpid()  # in the worker process
        busy = threading.Thread(target=procs.run, args=(_wait_for_file, str(release)))
        busy.start()
        assert poll(lambda: procs._free == 0, 60)
        with pytest.raises(NoFreeProcess):
            procs.run(_pid)
        # refused at once, not after waiting for the busy call: that call is still held
        assert busy.is_alive()
        release.touch()
        busy.join(60)
        assert not busy.is_alive()
        assert procs.run(abs, -3) == 3
        assert (procs.in_process, procs.inline, procs.crashes) == (3, 1, 0)
    finally:
        procs.close()
    with pytest.raises(NoFreeProcess):  # closed: nothing restarts behind the service's back
        procs.run(_pid)
    assert procs._pool is None


def _mark_then_sleep(path: str, t_s: float) -> None:
    open(path, "w").close()  # noqa: SIM115 (the test waits for it: the cycle is running now)
    time.sleep(t_s)


def test_closing_ends_the_processes_and_the_pool_thread_a_stuck_cycle_included(monkeypatch, tmp_path):
    """The stop does not leave the pool's ending to the interpreter's exit hooks (a race there
    once left a worker running and a service that ignored SIGTERM): a cycle still running
    after the grace is terminated, and nothing of the pool is left when close returns."""
    monkeypatch.setattr("api.service.cycles.runner.CLOSE_GRACE_S", 0.5)
    procs = CycleProcesses(1)
    procs.start()
    assert poll(lambda: started(procs), 60)
    pool = procs._pool
    workers = list(pool._processes.values())
    manager = pool._executor_manager_thread
    outcome = []

    def stuck():
        try:
            procs.run(_mark_then_sleep, str(tmp_path / "running"), 3600)
        except CycleProcessDied as exc:
            outcome.append(exc)

    busy = threading.Thread(target=stuck)
    busy.start()
    assert poll(lambda: (tmp_path / "running").exists(), 60)
    # the grace, then terminate: close returns although the cycle wanted an hour
    closing = threading.Thread(target=procs.close)
    closing.start()
    closing.join(120)
    assert not closing.is_alive()
    assert workers and not any(p.is_alive() for p in workers)
    assert not manager.is_alive()
    busy.join(10)
    assert not busy.is_alive() and len(outcome) == 1  # the cycle failed with a reason, not silently


def test_a_controller_only_this_process_can_reach_is_measured_here():
    procs = CycleProcesses(1)
    runner = DriverRunner(processes=procs)
    here = []
    runner.run_here = lambda axis, url: here.append(url)  # noqa: ARG005
    runner(AxisRecord(1, 1, "m", f.settings()), "canopen://virtual/0?node=3")
    assert here == ["canopen://virtual/0?node=3"] and procs.inline == procs.in_process == 0
    injected = DriverRunner(lambda url: None, processes=procs)  # an injected driver factory stays in-process
    assert injected.processes is None


def test_cycle_processes_setting():
    assert default_settings().cycle_processes == 2  # `mebm serve`
    assert parse_settings({"scheduler": {"cycle_processes": 0}}).cycle_processes == 0
    for bad in (-1, 65, 1.5, True):
        with pytest.raises(ConfigError, match="cycle_processes"):
            parse_settings({"scheduler": {"cycle_processes": bad}})


def _sim_service(tmp_path, processes: int) -> Service:
    settings = make_settings(f"sqlite:///{tmp_path}/db.sqlite3", tmp_path, cycle_processes=processes)
    axis = settings.axes[0]
    settings = replace(settings, axes=(replace(axis, settings=replace(axis.settings, controller_url="sim")),),
                       simulator=replace(settings.simulator, time_scale=20.0))
    svc = Service(settings)
    svc.start()
    return svc


def _cycles(svc, axis_id):
    with session_scope(svc.factory) as s:
        return results_repo.list_measurements(s, axis_id, limit=50)[1]


def test_the_service_measures_in_a_worker_process_and_survives_its_death(tmp_path):
    svc = _sim_service(tmp_path, 1)
    try:
        procs = svc.runner.processes
        with session_scope(svc.factory) as s:
            axis_id = config_repo.list_axes(s)[0].id
        assert poll(lambda: started(procs), 60) and svc.scheduler.idle(120)  # (a fresh sim axis measures at start)
        before = {c.id for c in _cycles(svc, axis_id)}
        # the start-up cycle ran inline or in the process, as the process was up or not by then
        in_process, inline = procs.in_process, procs.inline
        svc.trigger(axis_id, "test")
        assert svc.scheduler.idle(120)
        (first,) = [c for c in _cycles(svc, axis_id) if c.id not in before]
        assert first.status == "ok", first.failure_reason
        assert first.backlash_mean_um == pytest.approx(svc.simulators[axis_id].twin.backlash_um(first.temperature_c),
                                                       abs=15.0)
        assert (procs.in_process, procs.inline) == (in_process + 1, inline)
        # the process dies while its round trip runs (the simulated axis moves): that cycle fails
        # with the reason, and the next runs in a fresh process
        sim_axis = svc.simulators[axis_id].axis
        victims = list(procs._pool._processes.values())
        n = sim_axis.cycles_started
        svc.trigger(axis_id, "test")
        assert poll(lambda: sim_axis.cycles_started == n + 1, 30)
        for p in victims:
            p.kill()
        assert svc.scheduler.idle(120)
        before.add(first.id)
        (second,) = [c for c in _cycles(svc, axis_id) if c.id not in before]
        assert second.status == "failed" and "CycleProcessDied" in second.failure_reason
        assert procs.crashes == 1
        assert poll(lambda: started(procs), 60)
        svc.trigger(axis_id, "test")
        assert svc.scheduler.idle(120)
        third = _cycles(svc, axis_id)[0]
        assert third.status == "ok" and (procs.in_process, procs.inline) == (in_process + 2, inline)
        assert not set(procs._pool._processes.values()) & set(victims)
    finally:
        svc.stop()
    assert procs._pool is None


def test_a_process_that_ends_within_the_grace_is_not_reported_or_terminated(caplog):
    """end_pool must not take a process that has ended for one still running. The pool's
    manager thread reaps its processes too; when another thread wins the reaping,
    ``Process.join`` returns and ``is_alive`` stays true (waitpid: ECHILD), so an idle
    process that had ended on the stop was logged as "did not end within 10 s of the stop:
    terminated" a second after it (seen at `make run`). Here a third thread races for it as
    well; which thread wins varies, so the next test makes the lost race certain."""
    pool = spawn_pool(what="test", workers=1)
    assert pool.submit(_pid).result(timeout=60) != os.getpid()
    (proc,) = pool._processes.values()
    reaped = []

    def reap():
        try:
            reaped.append(os.waitpid(proc.pid, 0)[1])
        except ChildProcessError:  # the pool's manager thread reaped it first (proc.exitcode has it then)
            pass

    reaper = threading.Thread(target=reap, daemon=True)
    reaper.start()
    with caplog.at_level(logging.WARNING, logger="api.service.worker_process"):
        # a grace of an hour: end_pool returning at all shows the grace was not used up
        ending = threading.Thread(target=end_pool, args=(pool,), kwargs={"grace_s": 3600.0, "what": "test"})
        ending.start()
        ending.join(120)
        assert not ending.is_alive()
    assert "did not end" not in caplog.text
    reaper.join(5)
    # it ended by itself, not terminated, whichever thread reaped it
    assert (reaped and os.WIFEXITED(reaped[0]) and os.WEXITSTATUS(reaped[0]) == 0) or proc.exitcode == 0


def test_a_ctrl_c_is_left_to_the_service_not_taken_by_its_workers():
    """Ctrl-C signals the terminal's whole process group; the service ends its pools
    itself (end_pool). A worker that took SIGINT printed a KeyboardInterrupt traceback and
    died; it now ignores it and goes on working."""
    pool = spawn_pool(what="test", workers=1)
    try:
        pid = pool.submit(_pid).result(timeout=60)
        os.kill(pid, signal.SIGINT)
        time.sleep(0.5)
        assert pool.submit(_pid).result(timeout=60) == pid  # the same process, alive, still working
    finally:
        end_pool(pool, grace_s=5.0, what="test")


def test_a_process_reaped_by_another_thread_counts_as_ended():
    """The race above, made certain: the process has ended and another thread has reaped it
    (CPython's join() then returns at once and is_alive() stays true for ever, as waitpid
    fails with ECHILD). still_running, which end_pool uses, goes by the process' sentinel."""
    proc = multiprocessing.get_context("spawn").Process(target=abs, args=(-1,))
    proc.start()
    _, status = os.waitpid(proc.pid, 0)  # this thread reaps it, not the Process object
    assert os.WIFEXITED(status) and os.WEXITSTATUS(status) == 0
    found = []
    # a timeout of an hour: an answer at all is an answer at once, not after the timeout
    asking = threading.Thread(target=lambda: found.append(still_running([proc], 3600.0)))
    asking.start()
    asking.join(120)
    assert not asking.is_alive() and found == [[]]


def test_a_process_still_running_is_returned_after_the_timeout(monkeypatch):
    proc = multiprocessing.get_context("spawn").Process(target=time.sleep, args=(60,))
    proc.start()
    waited = []

    def wait_and_record(sentinels, timeout):
        waited.append(timeout)
        return wait_for_sentinels(sentinels, timeout)

    monkeypatch.setattr("api.service.worker_process.wait_for_sentinels", wait_and_record)
    try:
        assert still_running([proc], 0.5) == [proc]
        # it waited on the sentinel with the timeout, not without one
        assert waited and all(0.0 <= w <= 0.5 for w in waited) and waited[0] > 0.0
    finally:
        proc.kill()
        proc.join(5)
