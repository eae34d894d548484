"""RetryPolicy: attempts, back-off and budget counted with an injected sleep and clock."""

from __future__ import annotations

import asyncio

import pytest

from acquisition.errors import ControllerConnectionError, ControllerTimeoutError, ProtocolError
from acquisition.driver.retry import RetryPolicy
from core.errors import InputError


class FakeTime:
    """A clock that moves only when the policy sleeps (or a test advances it)."""

    def __init__(self):
        self.now, self.sleeps = 0.0, []

    def clock(self) -> float:
        return self.now

    async def sleep(self, s: float) -> None:
        self.sleeps.append(s)
        self.now += s


def _policy(t: FakeTime, **kw) -> RetryPolicy:
    return RetryPolicy(sleep=t.sleep, clock=t.clock, **kw)


def _failing(n_failures: int, exc_type=ControllerTimeoutError):
    calls = []

    async def op(attempt: int):
        calls.append(attempt)
        if len(calls) <= n_failures:
            raise exc_type(f"failure {len(calls)}")
        return "ok"

    return op, calls


def test_a_transient_failure_is_retried_with_exponential_back_off():
    t = FakeTime()
    op, calls = _failing(2)
    assert asyncio.run(_policy(t, attempts=3).run(op, retryable=lambda e: True)) == "ok"
    assert calls == [1, 2, 3] and t.sleeps == [0.05, 0.1]


def test_attempts_are_bounded_and_the_last_error_carries_their_count():
    t = FakeTime()
    op, calls = _failing(10)
    failures = []

    async def on_failure(exc):
        failures.append(str(exc))

    with pytest.raises(ControllerTimeoutError) as err:
        asyncio.run(_policy(t, attempts=4, backoff_max_s=0.15).run(op, retryable=lambda e: True, on_failure=on_failure))
    assert calls == [1, 2, 3, 4] and err.value.attempts == 4 and str(err.value) == "failure 4"
    assert t.sleeps == [0.05, 0.1, 0.15]  # capped; no pause after the last try
    assert failures == [f"failure {i}" for i in range(1, 5)]  # every failure seen (to close the link)


def test_a_failure_that_is_not_retryable_ends_at_once():
    t = FakeTime()
    op, calls = _failing(10, ProtocolError)
    with pytest.raises(ProtocolError):
        asyncio.run(_policy(t, attempts=5).run(op, retryable=lambda e: e.transient))
    assert calls == [1] and t.sleeps == []


def test_no_attempt_starts_past_the_budget():
    t = FakeTime()
    op, calls = _failing(10, ControllerConnectionError)
    # pauses 0.05, 0.1, 0.2: the fourth try would start at 0.35 s, past a 0.3 s budget
    with pytest.raises(ControllerConnectionError) as err:
        asyncio.run(_policy(t, attempts=10, budget_s=0.3).run(op, retryable=lambda e: True))
    assert calls == [1, 2, 3] and err.value.attempts == 3


def test_errors_outside_the_given_kinds_pass_through_untouched():
    t = FakeTime()
    op, calls = _failing(10, KeyError)
    with pytest.raises(KeyError):
        asyncio.run(_policy(t, attempts=5).run(op, retryable=lambda e: True, errors=(ControllerTimeoutError,)))
    assert calls == [1]


def test_variants_keep_the_injected_sleep_and_clock():
    t = FakeTime()
    p = _policy(t, attempts=3).with_(attempts=20, backoff_s=0.1, backoff_max_s=0.1)
    op, calls = _failing(4)
    assert asyncio.run(p.run(op, retryable=lambda e: True)) == "ok"
    assert t.sleeps == [0.1] * 4 and len(calls) == 5


@pytest.mark.parametrize("bad", [dict(attempts=0), dict(backoff_s=-1.0), dict(backoff_s=1.0, backoff_max_s=0.5)])
def test_policy_validation_names_the_value(bad):
    with pytest.raises(InputError):
        RetryPolicy(**bad)
