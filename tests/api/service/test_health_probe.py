"""The health report is answered from the last one while the checks run again on a
thread of their own; checks that hang past ``stale_s`` make the answer degraded, saying
so; an invalidated or long unasked-for report is computed before it is answered. The
checks are injected (a subclass) and the clock is turned by the test."""

from __future__ import annotations

import threading

from api.service.health import HealthProbe, HealthReport
from tests.clock import ManualClock
from tests.waiting import poll


def _report(problems=()) -> HealthReport:
    return HealthReport(database="ok", data_dir_writable=True, free_disk_bytes=10**9, min_free_disk_bytes=0,
                        problems=tuple(problems))


class Probe(HealthProbe):
    def __init__(self, **kw):
        self.time = ManualClock(1000.0)
        super().__init__(service=None, clock=self.time, **kw)
        self.answers = [_report()]
        self.gate = threading.Event()
        self.gate.set()
        self.checks = 0

    def _check(self) -> HealthReport:
        self.checks += 1
        assert self.gate.wait(30)
        return self.answers[-1]


def test_a_stale_report_is_answered_while_the_checks_run_again_and_the_new_one_follows():
    probe = Probe(ttl_s=2.0, stale_s=10.0)
    first = probe.report()  # the first: computed before it is answered
    assert first.ok and probe.checks == 1
    probe.gate.clear()  # the next checks take their time
    probe.answers.append(_report(["database: unavailable"]))
    probe.time.t += 2.5
    assert probe.report() is first  # answered at once...
    assert poll(lambda: probe.checks == 2, 10)  # ...while the checks run again
    probe.time.t += 1.0
    assert probe.report() is first and probe.checks == 2  # one refresh at a time
    probe.gate.set()
    assert poll(lambda: probe.report().problems == ("database: unavailable",), 10)


def test_checks_that_hang_past_stale_s_make_the_answer_degraded():
    probe = Probe(ttl_s=2.0, stale_s=10.0)
    probe.report()
    probe.gate.clear()  # the database stops answering
    probe.time.t += 2.5
    assert probe.report().ok  # the checks start again
    assert poll(lambda: probe.checks == 2, 10)
    probe.time.t += 9.0
    assert probe.report().ok  # not yet stale_s
    probe.time.t += 1.5
    hung = probe.report()
    assert hung.status == "degraded" and "have not answered for 10 s" in hung.problems[-1]
    probe.gate.set()
    assert poll(lambda: probe.report().ok, 10)


def test_an_invalidated_or_long_unasked_for_report_is_computed_before_it_is_answered():
    probe = Probe(ttl_s=2.0, stale_s=10.0)
    probe.report()
    probe.answers.append(_report(["free disk below the floor"]))
    probe.invalidate()
    assert probe.report(block=False) is None and probe.checks == 1  # the event loop runs no check
    assert probe.report().problems == ("free disk below the floor",) and probe.checks == 2
    probe.answers.append(_report())
    probe.time.t += 600.0  # nobody asked for ten minutes
    assert probe.report().ok and probe.checks == 3
