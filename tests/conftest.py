"""Test-wide settings.

Hypothesis searches with a fresh random seed on every run (profile ``default``); the
seed is printed in the session header, and a failing example is printed too, so a
failure found in CI can be replayed with ``pytest --hypothesis-seed=<seed>``. For a
reproducible local rerun of the same examples, set ``HYPOTHESIS_PROFILE=derandomize``;
``HYPOTHESIS_PROFILE=explore`` searches longer.
"""

import os

from hypothesis import settings

# derandomize=False spelled out: under CI=true Hypothesis loads its own "ci" profile
# (derandomize=True), which a profile registered here would otherwise inherit
settings.register_profile("default", derandomize=False, deadline=None, print_blob=True)
settings.register_profile("derandomize", derandomize=True, deadline=None)
settings.register_profile("explore", derandomize=False, deadline=None, max_examples=500, print_blob=True)
settings.load_profile(os.environ.get("HYPOTHESIS_PROFILE", "default"))

_SEED_OPTION = "--hypothesis-seed"


def pytest_configure(config):
    """Draw the run's Hypothesis seed here (unless one is given), so it can be printed."""
    if settings.default.derandomize:
        config.mebm_hypothesis_seed = None
        return
    seed = config.getoption(_SEED_OPTION)
    if seed is None:
        import random

        from hypothesis import core

        seed = random.SystemRandom().randrange(2**32)
        core.global_force_seed = seed
    config.mebm_hypothesis_seed = seed


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
