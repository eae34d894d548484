"""Repository: circular tests (ISO 230-4) and the alerts their decisions raise.

A circular test is stored with its machine, the two axes of its plane (names, and the
axes' ids when the machine has them), radius, feed, directions, temperature and
utility day, the test itself in core.circle.io's JSON (samples and instrument), its
figures, the agreement of each axis' reversal spikes with the TBE at its b̄, and each
axis' decision against its circle tasks.

Every function takes a Session, or an Engine (then it runs in its own transaction).
"""

from __future__ import annotations

import json
import math
from contextlib import contextmanager
from datetime import datetime

from sqlalchemy import Engine, or_, select
from sqlalchemy.orm import Session, defer

from core.circle.io import from_json, to_json
from core.circle.test import CircularTest
from core.errors import InputError
from storage.db.errors import NotFoundError
from storage.db.models import Alert, Axis, CircularTestRow, Machine
from storage.db.records import AlertRecord, CircularTestRecord, as_utc, utcnow
from storage.db.results_repo import ALERT_KIND, alert_record

STATES = ("OK", "WARNING", "ALARM")  # worst last


@contextmanager
def _session(s: Session | Engine):
    if isinstance(s, Engine):
        with Session(s, expire_on_commit=False) as session, session.begin():
            yield session
    else:
        yield s


def _dict(x) -> dict | None:
    if x is None:
        return None
    return x.to_dict() if hasattr(x, "to_dict") else dict(x)


def _dumps(x) -> str | None:
    return None if x is None else json.dumps(x, allow_nan=False)


def _clean(x):
    """NaN and infinities as null (JSON has neither)."""
    if isinstance(x, float) and not math.isfinite(x):
        return None
    if isinstance(x, dict):
        return {k: _clean(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [_clean(v) for v in x]
    return x


def _test_json(test: CircularTest) -> str:
    return json.dumps(to_json(test), allow_nan=False)


def _machine(s: Session, machine: int | str) -> Machine:
    m = s.get(Machine, machine) if isinstance(machine, int) else s.scalar(select(Machine).where(Machine.name == machine))
    if m is None:
        raise NotFoundError("machine", machine)
    return m


def _worst(decision: dict[str, dict | None]) -> str | None:
    states = [d.get("state") for d in decision.values() if d]
    states = [st for st in states if st in STATES]
    return max(states, key=STATES.index) if states else None


# -- writing -----------------------------------------------------------------------------------------
def add_circular_test(s: Session | Engine, machine: int | str, test: CircularTest, *, figures=None,
                      agreement: dict | None = None, decision: dict | None = None,
                      measured_at: datetime | None = None, recorded_by: str | None = None) -> int:
    """Store ``test`` on ``machine`` (id or name) with its analysis; returns the test's id.

    ``figures``: CircleFigures (or its dict); ``agreement``: axis name -> Agreement (or
    dict); ``decision``: axis name -> CircleDecision (or dict, or None when no task was
    judged). The plane's axes are linked to the machine's axes of those names; a name
    the machine does not have is an InputError."""
    if not isinstance(test, CircularTest):
        raise InputError("test must be a core.circle CircularTest")
    with _session(s) as s:
        m = _machine(s, machine)
        axes = {a.name: a.id for a in s.scalars(select(Axis).where(Axis.machine_id == m.id))}
        missing = [a for a in test.plane if a not in axes]
        if missing:
            raise InputError(f"plane {test.plane}: machine {m.name!r} has no axis {', '.join(map(repr, missing))} "
                             f"(its axes: {', '.join(sorted(axes)) or 'none'})")
        for key, per_axis in (("agreement", agreement), ("decision", decision)):
            extra = set(per_axis or {}) - set(test.plane)
            if extra:
                raise InputError(f"{key}: axis {sorted(extra)} is not in the plane {test.plane}")
        agreement_d = {a: _clean(_dict(v)) for a, v in (agreement or {}).items()}
        decision_d = {a: _clean(_dict(v)) for a, v in (decision or {}).items()}
        now = utcnow()
        row = CircularTestRow(
            machine_id=m.id, first_axis=test.plane[0], second_axis=test.plane[1],
            first_axis_id=axes[test.plane[0]], second_axis_id=axes[test.plane[1]], radius_mm=test.radius_mm,
            feed_mm_min=test.feed_mm_min, directions=",".join(p.direction for p in test.passes),
            temperature_c=test.temperature_c, utility_day=test.utility_day, measured_at=measured_at or now,
            recorded_at=now, recorded_by=recorded_by, source=test.source or "",
            instrument=json.dumps({"kind": test.instrument.kind, "resolution_um": test.instrument.resolution_um,
                                   "accuracy_um": test.instrument.accuracy_um, "name": test.instrument.name}),
            test=_test_json(test), figures=_dumps(_clean(_dict(figures))), agreement=_dumps(agreement_d),
            decision=_dumps(decision_d), state=_worst(decision_d),
        )
        s.add(row)
        s.flush()
        return row.id


# -- reading -----------------------------------------------------------------------------------------
def _record(row: CircularTestRow, machine_name: str, *, samples: bool) -> CircularTestRecord:
    return CircularTestRecord(
        id=row.id, machine_id=row.machine_id, machine_name=machine_name, plane=(row.first_axis, row.second_axis),
        axis_ids=(row.first_axis_id, row.second_axis_id), radius_mm=row.radius_mm, feed_mm_min=row.feed_mm_min,
        directions=tuple(row.directions.split(",")), temperature_c=row.temperature_c, utility_day=row.utility_day,
        measured_at=as_utc(row.measured_at), recorded_at=as_utc(row.recorded_at), recorded_by=row.recorded_by,
        source=row.source, instrument=json.loads(row.instrument),
        figures=json.loads(row.figures) if row.figures else None,
        agreement=json.loads(row.agreement) if row.agreement else {},
        decision=json.loads(row.decision) if row.decision else {}, state=row.state,
        test=from_json(json.loads(row.test)) if samples else None,
    )


def get_circular_test(s: Session | Engine, test_id: int) -> CircularTestRecord:
    """The test with its samples (``record.test``, a CircularTest), figures, agreement and decision."""
    with _session(s) as s:
        row = s.get(CircularTestRow, test_id)
        if row is None:
            raise NotFoundError("circular test", test_id)
        return _record(row, s.scalar(select(Machine.name).where(Machine.id == row.machine_id)), samples=True)


def _axis_filter(s: Session, m: Machine, axis: int | str):
    if isinstance(axis, int):
        a = s.get(Axis, axis)
        if a is None or a.machine_id != m.id:
            raise NotFoundError("axis", axis)
    else:
        a = s.scalar(select(Axis).where(Axis.machine_id == m.id, Axis.name == axis))
        if a is None:
            raise NotFoundError("axis", f"{m.name}/{axis}")
    return or_(CircularTestRow.first_axis_id == a.id, CircularTestRow.second_axis_id == a.id)


def list_circular_tests(s: Session | Engine, machine: int | str, axis: int | str | None = None, limit: int = 100,
                        *, offset: int = 0, samples: bool = False) -> list[CircularTestRecord]:
    """The machine's tests (of one axis: id or name, when given), newest first; without
    their samples (``record.test`` None) unless ``samples``."""
    if not isinstance(limit, int) or limit < 1:
        raise InputError(f"limit (={limit!r}) must be an integer >= 1")
    with _session(s) as s:
        m = _machine(s, machine)
        q = select(CircularTestRow).where(CircularTestRow.machine_id == m.id)
        if not samples:  # (the samples are most of a row: a LinuxCNC recording is megabytes)
            q = q.options(defer(CircularTestRow.test))
        if axis is not None:
            q = q.where(_axis_filter(s, m, axis))
        rows = s.scalars(q.order_by(CircularTestRow.measured_at.desc(), CircularTestRow.id.desc())
                         .limit(limit).offset(offset))
        return [_record(r, m.name, samples=samples) for r in rows]


def count_circular_tests(s: Session | Engine, machine: int | str, axis: int | str | None = None) -> int:
    from sqlalchemy import func

    with _session(s) as s:
        m = _machine(s, machine)
        q = select(func.count()).select_from(CircularTestRow).where(CircularTestRow.machine_id == m.id)
        if axis is not None:
            q = q.where(_axis_filter(s, m, axis))
        return int(s.scalar(q) or 0)


def latest_circular_test(s: Session | Engine, axis_id: int) -> CircularTestRecord | None:
    """The axis' newest test (without samples), or None."""
    with _session(s) as s:
        row = s.scalar(select(CircularTestRow).options(defer(CircularTestRow.test))
                       .where(or_(CircularTestRow.first_axis_id == axis_id, CircularTestRow.second_axis_id == axis_id))
                       .order_by(CircularTestRow.measured_at.desc(), CircularTestRow.id.desc()).limit(1))
        if row is None:
            return None
        return _record(row, s.scalar(select(Machine.name).where(Machine.id == row.machine_id)), samples=False)


# -- alerts ------------------------------------------------------------------------------------------
def update_alerts(s: Session | Engine, axis_id: int, test_id: int, decision: dict | None, *,
                  at: datetime | None = None) -> list[AlertRecord]:
    """The alert transition of one axis after a circular test judged it (``decision``:
    CircleDecision.to_dict(), None when no task matched: nothing changes).

    The same alert as a round trip's decision raises (kind ``tbe_exceeded``, the judged
    task, its error and tolerance), with the test as its evidence. One such alert per axis
    while active; the next circular test of the axis judged below ALARM clears it. A
    round trip's decision neither clears it nor is cleared by it: the two measure
    differently and each answers for its own alert."""
    if not decision:
        return []
    at = at or utcnow()
    with _session(s) as s:
        # the axis row locked (PostgreSQL): two tests of one axis stored at once raise one alert.
        # FOR NO KEY UPDATE: it waits for another such lock, not for the key-share locks the
        # tests' own foreign keys to the axis take (FOR UPDATE would deadlock with those)
        if s.scalar(select(Axis.id).where(Axis.id == axis_id).with_for_update(key_share=True)) is None:
            raise NotFoundError("axis", axis_id)
        active = s.scalar(select(Alert).where(Alert.axis_id == axis_id, Alert.kind == ALERT_KIND,
                                              Alert.raised_by_circle_id.is_not(None), Alert.cleared_at.is_(None)))
        state = decision.get("state")
        if state == "ALARM" and active is None:
            a = Alert(axis_id=axis_id, kind=ALERT_KIND, raised_at=at, raised_by_circle_id=test_id,
                      task_name=decision.get("task") or decision.get("task_name"), tbe_um=decision.get("error_um"),
                      tolerance_um=decision.get("tolerance_um"),
                      message=f"circular test {test_id}: {decision.get('message') or decision.get('reason') or 'ALARM'}")
            s.add(a)
            s.flush()
            return [alert_record(s, a)]
        if state != "ALARM" and active is not None:
            active.cleared_at = at
            active.cleared_by_circle_id = test_id
            s.flush()
            return [alert_record(s, active)]
        return []
