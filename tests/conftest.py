"""Test-wide settings.

Hypothesis searches with a fresh random seed on every run (profile ``default``); the
seed is printed in the session header, and a failing example is printed too, so a
failure found in CI can be replayed with ``pytest --hypothesis-seed=<seed>``. For a
reproducible local rerun of the same examples, set ``HYPOTHESIS_PROFILE=derandomize``;
``HYPOTHESIS_PROFILE=explore`` searches longer.
"""

import os

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


# Test files that take a host-wide turn (tests/host_lock.py) and the lock's name: under
# ``--dist loadfile`` the files of one lock are one unit of work, run by one worker one
# after the other, instead of files in several workers of which all but one wait for the
# lock (at the end of a run, where pytest-xdist's order puts files of few tests, the
# cores then stood idle).
HOST_TURNS = {
    "tests/acquisition/linuxcnc/": "linuxcnc",
    "tests/acquisition/canopen/test_driver_netns.py": "realtime-rig",
    "tests/acquisition/canopen/test_listen_netns.py": "realtime-rig",
}


def work_unit(nodeid: str) -> str:
    """The unit of work of a test under ``--dist loadfile``: its file, or its host lock's
    name (HOST_TURNS)."""
    path = nodeid.split("::", 1)[0]
    return next((lock for prefix, lock in HOST_TURNS.items() if path.startswith(prefix)), path)


@pytest.hookimpl(optionalhook=True)
def pytest_xdist_make_scheduler(config, log):
    """``--dist loadfile`` with the files of one host lock in one unit (HOST_TURNS)."""
    if config.getoption("dist") != "loadfile":
        return None
    from xdist.scheduler import LoadFileScheduling

    class HostTurnsScheduling(LoadFileScheduling):
        def _split_scope(self, nodeid: str) -> str:
            return work_unit(nodeid)

    return HostTurnsScheduling(config, log)


def _seed_line(config) -> str | None:
    seed = getattr(config, "mebm_hypothesis_seed", None)
    if seed is None:
        return None
    return f"hypothesis seed: {seed} (replay with: pytest {_SEED_OPTION}={seed})"


def pytest_report_header(config):
    return _seed_line(config)


def pytest_terminal_summary(terminalreporter, exitstatus, config):
    line = _seed_line(config)
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
