"""Test-wide settings.

Hypothesis searches with a fresh random seed on every run (profile ``default``); the
seed is printed in the session header, and a failing example is printed too, so a
failure found in CI can be replayed with ``pytest --hypothesis-seed=<seed>``. For a
reproducible local rerun of the same examples, set ``HYPOTHESIS_PROFILE=derandomize``;
``HYPOTHESIS_PROFILE=explore`` searches longer.
"""

import os
import subprocess
import sys
import tempfile

import pytest
from hypothesis import settings

# derandomize=False spelled out: under CI=true Hypothesis loads its own "ci" profile
# (derandomize=True), which a profile registered here would otherwise inherit
settings.register_profile("default", derandomize=False, deadline=None, print_blob=True)
settings.register_profile("derandomize", derandomize=True, deadline=None)
settings.register_profile("explore", derandomize=False, deadline=None, max_examples=500, print_blob=True)
settings.load_profile(os.environ.get("HYPOTHESIS_PROFILE", "default"))

_SEED_OPTION = "--hypothesis-seed"


def pytest_configure(config):
    """Draw the run's Hypothesis seed here (unless one is given), so it can be printed.
    Under pytest-xdist the controller draws it and every worker uses the same one, so
    the printed seed replays a failure whichever worker ran the test."""
    if settings.default.derandomize:
        config.mebm_hypothesis_seed = None
        return
    seed = config.getoption(_SEED_OPTION)
    if seed is None:
        from hypothesis import core

        worker_input = getattr(config, "workerinput", None)
        if worker_input is not None and worker_input.get("mebm_hypothesis_seed") is not None:
            seed = worker_input["mebm_hypothesis_seed"]
        else:
            import random

            seed = random.SystemRandom().randrange(2**32)
        core.global_force_seed = seed
    config.mebm_hypothesis_seed = seed


@pytest.hookimpl(optionalhook=True)
def pytest_configure_node(node):
    """(pytest-xdist, on the controller) hand the run's seed to each worker."""
    node.workerinput["mebm_hypothesis_seed"] = getattr(node.config, "mebm_hypothesis_seed", None)


@pytest.hookimpl(optionalhook=True)
def pytest_xdist_auto_num_workers(config):
    """``-n auto``: two workers per core. Much of the suite waits on something that runs at
    its own pace (simulated controllers slower than real time, LinuxCNC's servo thread,
    services starting and stopping, a browser), and a second worker per core computes
    meanwhile. ``PYTEST_XDIST_AUTO_NUM_WORKERS`` still sets the number."""
    given = os.environ.get("PYTEST_XDIST_AUTO_NUM_WORKERS", "").strip()
    if given.isdigit() and int(given) > 0:
        return int(given)
    return 2 * (len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count() or 1)


_COMPILE = "from tests.numba_kernels import compile_kernels; compile_kernels()"


@pytest.hookimpl(tryfirst=True)
def pytest_sessionstart(session):
    """(the controller of a parallel run) compile the numba kernels in another process
    while the workers start and collect (tests/numba_kernels.py): on a fresh clone each
    worker would otherwise compile every kernel itself. A worker that needs a kernel
    before it is written compiles it, as without this."""
    config = session.config
    if getattr(config, "workerinput", None) is not None or not config.getoption("numprocesses", None):
        return
    log = tempfile.TemporaryFile()
    proc = subprocess.Popen([sys.executable, "-c", _COMPILE], cwd=config.rootpath, stdout=log,
                            stderr=subprocess.STDOUT)  # fmt: skip
    config.mebm_kernels = (proc, log)


def _kernels_line(config) -> str | None:
    """A line for the summary when compiling the kernels failed (the product code it runs raised)."""
    started = getattr(config, "mebm_kernels", None)
    if started is None:
        return None
    proc, log = started
    try:
        rc = proc.wait(timeout=60)
    except subprocess.TimeoutExpired:
        proc.kill()
        return "compiling the numba kernels did not end in the run's time: killed"
    if rc == 0:
        return None
    log.seek(0)
    tail = log.read().decode(errors="replace").strip().splitlines()[-1:]
    return f"compiling the numba kernels failed (exit {rc}): {' '.join(tail)} (run: python -c '{_COMPILE}')"


def _seed_line(config) -> str | None:
    seed = getattr(config, "mebm_hypothesis_seed", None)
    if seed is None:
        return None
    return f"hypothesis seed: {seed} (replay with: pytest {_SEED_OPTION}={seed})"


def pytest_report_header(config):
    return _seed_line(config)


def pytest_terminal_summary(terminalreporter, exitstatus, config):
    for line in (_seed_line(config), _kernels_line(config)):
        if line:
            terminalreporter.write_line(line)


@pytest.fixture(autouse=True)
def _apps_end_with_their_test():
    """A worker process starts hundreds of apps, one per test, where a server starts one.
    FastAPI classifies endpoints and dependencies through process-wide LRU caches keyed by
    the callables (``fastapi.dependencies.models``, 4096 entries); the apps' endpoints are
    closures over their app and service, so those caches kept the last few dozen apps, and
    every service they held, alive: ~22,000 objects a test, and a heap whose full
    collections grew to seconds on a loaded host, inside transactions with a 2 s idle
    limit. Emptied after each test, an app ends with its test."""
    yield
    import sys

    models = sys.modules.get("fastapi.dependencies.models")
    if models is not None:
        for value in vars(models).values():
            clear = getattr(value, "cache_clear", None)
            if callable(clear):
                clear()


def pytest_unconfigure(config):
    started = getattr(config, "mebm_kernels", None)
    if started is not None and started[0].poll() is None:
        started[0].kill()
        started[0].wait()
