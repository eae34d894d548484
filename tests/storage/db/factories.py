"""Test data: a synthetic round trip with a known backlash, the demo axis and tasks."""

from __future__ import annotations

import uuid
from datetime import datetime, timedelta, timezone

import numpy as np

from core.criteria import analyze_round_trip
from core.dataset import AxisSpec
from core.tbe import MachiningTask, decide
from storage.db import AxisSettings, FinishedCycle, Schedule

AXIS = AxisSpec("y", transmission_mm_per_rev=6.857, screw_lead_mm=16.0, position_gain_per_s=10.0,
                travel_mm=(0.0, 200.0))
CIRCLE = MachiningTask("circle R200", "circle", feed_mm_min=200.0, gain_per_s=10.0, tolerance_um=45.0,
                       radius_mm=200.0)
LINE = MachiningTask("line 30deg", "line", feed_mm_min=1000.0, gain_per_s=10.0, tolerance_um=80.0, angle_deg=30.0)


def settings(**kw) -> AxisSettings:
    base = dict(spec=AXIS, controller_url="modbus://127.0.0.1:1502", schedule=Schedule(interval_s=60.0),
                tasks=(CIRCLE,))
    base.update(kw)
    return AxisSettings(**base)


def trace(backlash_um: float, *, start_mm=-5.0, end_mm=205.0, step_mm=0.05, cyclic_um=2.0):
    """(time_s, motor_rev, table_mm) of a round trip through a play of ``backlash_um``."""
    up = np.arange(start_mm, end_mm, step_mm)
    cmd = np.concatenate([up, up[::-1]])
    h = backlash_um * 1e-3 / 2
    table = np.empty_like(cmd)
    x = cmd[0] + h
    for i, p in enumerate(cmd):
        x = min(max(x, p - h), p + h)
        table[i] = x
    table = table + cyclic_um * 1e-3 * np.sin(2 * np.pi * table / 16.0)
    t = np.arange(cmd.size) * 0.01
    return t, cmd / AXIS.transmission_mm_per_rev, table


def round_trip(backlash_um: float):
    t, m, x = trace(backlash_um)
    return analyze_round_trip(t, m, x, AXIS)


def finished(axis_id: int, backlash_um: float | None, *, when: datetime | None = None, status: str = "ok",
             temperature_c: float = 20.0, tasks=(CIRCLE,), reason: str | None = None) -> FinishedCycle:
    when = when or datetime.now(timezone.utc)
    rt = round_trip(backlash_um) if status == "ok" else None
    dec = decide(rt.backlash.mean_um, tasks) if rt is not None and tasks else None
    return FinishedCycle(
        uuid=str(uuid.uuid4()), axis_id=axis_id, trigger="schedule", status=status,
        requested_at=when - timedelta(seconds=5), started_at=when - timedelta(seconds=4), finished_at=when,
        failure_reason=reason, temperature_c=temperature_c, utility_day=0.0, uncertainty_um=1.5,
        run_file="rt_y_0001.csv" if rt is not None else None, round_trip=rt, decision=dec,
    )
