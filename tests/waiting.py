"""Waiting in tests for what another thread or process does: a deadline for a hang, not a
performance bound (performance is measured in ``benchmarks/``)."""

from __future__ import annotations

import time
from collections.abc import Callable
from typing import TypeVar

T = TypeVar("T")


def poll(pred: Callable[[], T], timeout_s: float = 60.0, interval_s: float = 0.05) -> T:
    """The first truthy value of ``pred()`` within ``timeout_s``; else its value at the
    deadline (falsy), for the caller's ``assert``."""
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        v = pred()
        if v:
            return v
        time.sleep(interval_s)
    return pred()


def until(pred: Callable[[], T], what: str, limit_s: float = 30.0, interval_s: float = 0.05) -> T:
    """Like :func:`poll`, but an :class:`AssertionError` naming ``what`` at the deadline."""
    v = poll(pred, limit_s, interval_s)
    if not v:
        raise AssertionError(f"{what} did not happen within {limit_s:g} s")
    return v
