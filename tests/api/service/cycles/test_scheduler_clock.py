"""The service's clock runs a job that starts late, once, instead of skipping it."""

import threading
from datetime import datetime, timedelta, timezone

from api.service.cycles.scheduler import CycleScheduler
from tests.waiting import poll


def test_a_one_shot_job_due_seconds_ago_still_runs():
    """A verification cycle's date job (api.service.maintenance.loop) that the clock reaches 5 s
    late, as on a busy host: APScheduler's default 1 s misfire grace would skip it for good."""
    sch = CycleScheduler(None, None)
    ran = threading.Event()
    sch.clock.start()
    try:
        sch.clock.add_job(ran.set, "date", run_date=datetime.now(timezone.utc) - timedelta(seconds=5), id="late")
        assert ran.wait(10.0), "a job due 5 s ago was skipped as missed"
        # the clock's own thread removes the spent job after handing it out: let it, so the
        # shutdown below does not race it
        assert poll(lambda: sch.clock.get_job("late") is None)
    finally:
        sch.clock.shutdown(wait=True)

