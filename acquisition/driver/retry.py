"""One retry policy for every exchange of a driver: how often, how long apart, within what budget.

The driver's exchanges (the connection set-up, each request of the measurement loop, the
abort after a failure) differ only in which failures they retry and what they do between
attempts (close the link, note the trouble); the counting, the back-off and the time budget
are this one object. Sleep and clock are injected, so tests count attempts and delays
without waiting for them.
"""

from __future__ import annotations

import asyncio
import time
from collections.abc import Awaitable, Callable
from dataclasses import dataclass, field, replace
from typing import TypeVar

from core.errors import InputError

T = TypeVar("T")


@dataclass(frozen=True)
class RetryPolicy:
    """``attempts`` tries in all (1: no retry). Before try n+1 it waits
    ``min(backoff_s * 2**n, backoff_max_s)`` (``backoff_max_s == backoff_s``: a constant
    pause). With ``budget_s``, no new try starts once that long has passed since the first
    one began (or would start after it, given the pause).
    """

    attempts: int = 3
    backoff_s: float = 0.05
    backoff_max_s: float = 0.5
    budget_s: float | None = None
    sleep: Callable[[float], Awaitable[None]] = field(default=asyncio.sleep, compare=False, repr=False)
    clock: Callable[[], float] = field(default=time.monotonic, compare=False, repr=False)

    def __post_init__(self) -> None:
        if self.attempts < 1:
            raise InputError(f"attempts (={self.attempts}) must be >= 1")
        if not (self.backoff_s >= 0 and self.backoff_max_s >= self.backoff_s):
            raise InputError(f"backoff_s (={self.backoff_s}) must be >= 0 and <= backoff_max_s (={self.backoff_max_s})")

    def with_(self, **changes) -> "RetryPolicy":
        """A variant for one kind of exchange (fewer attempts, a budget), same sleep and clock."""
        return replace(self, **changes)

    def delay_s(self, attempt: int) -> float:
        """Pause after the ``attempt``-th failed try (1-based)."""
        return min(self.backoff_s * 2 ** (attempt - 1), self.backoff_max_s)

    async def run(
        self,
        op: Callable[[int], Awaitable[T]],
        *,
        retryable: Callable[[Exception], bool],
        on_failure: Callable[[Exception], Awaitable[None]] | None = None,
        errors: tuple[type[BaseException], ...] = (Exception,),
    ) -> T:
        """``await op(attempt)`` until it returns; a failure in ``errors`` runs ``on_failure``
        and is retried if ``retryable`` says so and attempts and budget remain, else re-raised
        with ``exc.attempts`` set to the tries made."""
        t0 = self.clock()
        attempt = 0
        while True:
            attempt += 1
            try:
                return await op(attempt)
            except errors as exc:
                if on_failure is not None:
                    await on_failure(exc)
                pause = self.delay_s(attempt)
                over_budget = self.budget_s is not None and self.clock() + pause - t0 > self.budget_s
                if attempt >= self.attempts or over_budget or not retryable(exc):
                    exc.attempts = attempt
                    raise
            await self.sleep(pause)
