"""Worker processes of the service: a ``spawn``-started pool that ends with the service.

Used for the CPU work a request or a cycle would otherwise do on the service's own interpreter
(gap diagnoses, figure renders, the cycles' acquisition and analysis): pure Python, numpy and matplotlib hold the interpreter lock
while they run, and every status poll then waits for it. In a separate process they only
share the CPU.

``spawn``, not ``fork``: the service has threads, and a fork would copy locks they hold.
A pool worker whose parent was killed (SIGKILL, a crash) waits forever on its call queue,
whose pipe it holds open itself (seen as orphaned idle processes after killed services),
so a watchdog thread ends it once its parent is gone: at once where the parent can be
waited on (a pidfd), else within ``PARENT_POLL_S``.
"""

from __future__ import annotations

import importlib
import logging
import multiprocessing
import os
import select
import signal
import threading
import time
from concurrent.futures import ProcessPoolExecutor
from multiprocessing.connection import wait as wait_for_sentinels

log = logging.getLogger(__name__)

PARENT_POLL_S = 2.0
# an idle worker ends within milliseconds of the stop; one still busy after this is
# terminated by end_pool when its work is asked again rather than waited for
IDLE_END_S = 1.0


def _worker_init(parent_pid: int, nice: int, what: str, imports: tuple[str, ...] = (),
                 log_level: int | None = None) -> None:
    # Ctrl-C in a terminal signals the whole process group: the service stops its pools
    # (end_pool), and a worker that took the interrupt itself printed a KeyboardInterrupt
    # traceback per process at every Ctrl-C of `make run`
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    if log_level is not None:  # the service's log lines, from this process too (on stderr, like the service's)
        logging.basicConfig(level=log_level, format=f"%(asctime)s %(levelname)s %(name)s [{what} process]: %(message)s")
    for name in imports:  # warm: the first task does not pay the imports
        importlib.import_module(name)
    if nice:
        try:
            os.nice(nice)
        except OSError:  # not permitted here: run at the service's priority
            log.warning("the %s process could not lower its priority", what)

    def watch() -> None:
        try:  # readable once the parent has ended (Linux 5.3+)
            parent = os.pidfd_open(parent_pid)
        except (AttributeError, OSError):
            parent = None
        if parent is not None and os.getppid() == parent_pid:  # the fd is of the parent, not of a reused pid
            select.select([parent], [], [])
        while os.getppid() == parent_pid:
            time.sleep(PARENT_POLL_S)
        os._exit(0)

    threading.Thread(target=watch, name=f"mebm-{what}-parent-watch", daemon=True).start()


def spawn_pool(*, what: str, nice: int = 0, workers: int = 1, imports: tuple[str, ...] = (),
               log_level: int | None = None) -> ProcessPoolExecutor:
    """A pool of ``workers`` spawned processes at ``nice`` above the service, each ending
    when the service ends; ``what`` names them in log lines. Each imports ``imports`` when it
    starts, and with ``log_level`` logs to stderr as the service does."""
    return ProcessPoolExecutor(max_workers=workers, mp_context=multiprocessing.get_context("spawn"),
                               initializer=_worker_init, initargs=(os.getpid(), nice, what, tuple(imports), log_level))


def end_pool(pool: ProcessPoolExecutor, *, grace_s: float, what: str) -> None:
    """Shut ``pool`` down and make sure its processes and its manager thread are gone.

    ``shutdown(wait=False)`` alone leaves the ending to ``concurrent.futures``' exit hook,
    which races with the manager thread closing its wake-up pipe (seen: ``OSError: [Errno 9]
    Bad file descriptor`` in ``_python_exit``, then a worker never told to stop, and
    ``multiprocessing``'s own exit hook joining it for ever: a service that ignored SIGTERM).
    So: no new work, queued work cancelled; a task still running gets ``grace_s`` to finish;
    then the processes are terminated (killed if they ignore it) and the manager thread joined.
    """
    manager = getattr(pool, "_executor_manager_thread", None)  # shutdown() forgets them: take them first
    procs = list((getattr(pool, "_processes", None) or {}).values())
    pool.shutdown(wait=False, cancel_futures=True)
    left = still_running(procs, grace_s)
    if left:
        log.warning("the %s process(es) %s did not end within %g s of the stop: terminated", what,
                    ", ".join(str(p.pid) for p in left), grace_s)
    for p in left:
        p.terminate()
    for p in still_running(left, 2.0):
        p.kill()
    still_running(left, 2.0)
    for p in left:  # reap what was terminated (a no-op where the manager thread did)
        p.join(0)
    if manager is not None and manager.is_alive():
        manager.join(5.0)


def still_running(procs: list[multiprocessing.Process], timeout_s: float) -> list[multiprocessing.Process]:
    """The processes of ``procs`` that have not ended within ``timeout_s``.

    Waits on their sentinels (a pipe the process holds until it ends), not ``join()``: the
    pool's manager thread joins its processes too, and of two threads reaping one child the
    loser's ``waitpid`` fails (ECHILD), which ``multiprocessing`` takes for "still running".
    A process that had ended cleanly was then reported as not ending within the grace and
    "terminated" (seen at ``make run``'s stop during the cycle processes' start-up).
    """
    pending = {p.sentinel: p for p in procs}
    deadline = time.monotonic() + timeout_s
    while pending:
        for s in wait_for_sentinels(list(pending), max(deadline - time.monotonic(), 0.0)):
            pending.pop(s)
        if time.monotonic() >= deadline:
            break
    return list(pending.values())
