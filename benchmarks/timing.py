"""Shared timing for the benchmark scripts: medians, never single runs."""

from __future__ import annotations

import platform
import statistics
import time
from collections.abc import Callable


def median_s(fn: Callable[[], object], repeats: int, *, warm_up: bool = True) -> float:
    """Median wall time of ``fn()`` over ``repeats`` calls, in seconds.

    ``warm_up`` makes one untimed call first (numba compilation, caches)."""
    if warm_up:
        fn()
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return statistics.median(times)


def cpu_name() -> str:
    """The CPU's model name (from /proc/cpuinfo), for a benchmark's printout."""
    try:
        for line in open("/proc/cpuinfo", encoding="utf-8"):
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or "unknown CPU"
