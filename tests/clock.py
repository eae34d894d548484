"""The tests' injected clock: seconds that pass only when a test says so (``clock.t += 5``)."""

from __future__ import annotations


class ManualClock:
    """A clock for the product's ``clock=`` parameters (``time.monotonic``'s place)."""

    def __init__(self, t: float = 0.0):
        self.t = t

    def __call__(self) -> float:
        return self.t
