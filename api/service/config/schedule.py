"""An axis' stored schedule read as a clock: the APScheduler trigger that fires it.

Configuration input checks a cron expression with it (a schedule the clock cannot read
is refused when it is written), and the schedulers (:mod:`api.service.cycles`) run on it:
the cycles depend on the configuration, never the other way round.
"""

from __future__ import annotations

from datetime import datetime, timezone

from apscheduler.triggers.cron import CronTrigger
from apscheduler.triggers.interval import IntervalTrigger

from core.errors import InputError
from storage.db import Schedule


def make_trigger(schedule: Schedule):
    """The APScheduler trigger of a stored schedule (cron fields in UTC)."""
    if schedule.interval_s is not None:
        return IntervalTrigger(seconds=schedule.interval_s, timezone=timezone.utc)
    try:
        trigger = CronTrigger.from_crontab(schedule.cron, timezone=timezone.utc)
    except ValueError as exc:
        raise InputError(f"schedule: cron (={schedule.cron!r}) is not a valid crontab expression: {exc}") from exc
    if trigger.get_next_fire_time(None, datetime.now(timezone.utc)) is None:
        raise InputError(f"schedule: cron (={schedule.cron!r}) never fires (a date that does not exist?)")
    return trigger
