"""Circular tests (ISO 230-4) in the service: analyse, compare, judge, store, alert.

A test posted to a machine is analysed (core.circle.analyze: G, H, F, the reversal
spikes, each with its expanded uncertainty); each axis of its plane gets

- the *agreement* of its spikes with the TBE that Eq. 8 predicts at the axis' latest b̄
  (its U carried through) and the axis' K (core.circle.compare_with_backlash), when the
  axis has a round trip stored;
- the *decision* against its circle tasks at the test's radius and feed
  (core.circle.decide_circle: the same rule and guard bands as the round trip's).

Stored in one transaction with the alert transition of each judged axis (the same
``tbe_exceeded`` alert a round trip's decision raises, with the test as its evidence).
Then the events go out (alerts on MQTT and webhooks, the axes' status refreshed on every
interface) and the maintenance loop opens the work order of a WARNING or ALARM, or
concludes the verification of a repaired order with the test.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass
from datetime import datetime

from api.service.events import Event
from core.circle import CircularTest, analyze
from core.circle.agreement import compare_with_backlash
from core.circle.decision import CircleDecision, decide_circle
from core.errors import InputError
from storage.db import (
    AlertRecord,
    AxisRecord,
    CircularTestRecord,
    NotFoundError,
    circles_repo,
    config_repo,
    results_repo,
    session_scope,
    utcnow,
)

log = logging.getLogger("mebm.circles")


@dataclass(frozen=True)
class StoredCircle:
    """What posting a test did: the stored record, the alerts it raised or cleared, and
    per axis the decision (None: no circle task of the axis at this radius and feed)."""

    record: CircularTestRecord
    alerts: tuple[AlertRecord, ...]
    decisions: dict[str, CircleDecision | None]
    axes: dict[str, AxisRecord]


def _plane_axes(s, machine_id: int, test: CircularTest) -> dict[str, AxisRecord]:
    axes = {a.name: a for a in config_repo.list_axes(s, machine_id)}
    if not axes and not any(m.id == machine_id for m in config_repo.list_machines(s)):
        raise NotFoundError("machine", machine_id)
    missing = [a for a in test.plane if a not in axes]
    if missing:
        machine = next(iter(axes.values())).machine_name if axes else str(machine_id)
        raise InputError(f"plane {list(test.plane)}: machine {machine!r} has no axis "
                         f"{', '.join(map(repr, missing))} (its axes: {', '.join(sorted(axes)) or 'none'})")
    return {name: axes[name] for name in test.plane}


def analyse(s, machine_id: int, test: CircularTest):
    """(axes, figures, agreement per axis, decision per axis) of ``test`` on the machine."""
    axes = _plane_axes(s, machine_id, test)
    figures = analyze(test)
    agreement, decisions = {}, {}
    for name, axis in axes.items():
        latest = results_repo.latest_result(s, axis.id)
        if latest is not None:
            rt = latest.round_trip
            agreement[name] = compare_with_backlash(
                figures, axis=name, backlash_um=max(rt.backlash.mean_um, 0.0),
                backlash_uncertainty_um=rt.backlash_mean_uncertainty_um if rt.budgets else 0.0,
                gain_per_s=axis.spec.position_gain_per_s)
        decisions[name] = decide_circle(figures, axis.tasks, axis=name,
                                        warning_fraction=axis.settings.warning_fraction,
                                        rule=axis.settings.decision_rule) if axis.tasks else None
    return axes, figures, agreement, decisions


def record_circular_test(svc, machine_id: int, test: CircularTest, *, by: str | None,
                         measured_at: datetime | None = None) -> StoredCircle:
    """Analyse, judge and store ``test`` on the machine; raise and clear alerts; publish
    the events and let the maintenance loop act on the decisions."""
    with session_scope(svc.factory) as s:
        axes, figures, agreement, decisions = analyse(s, machine_id, test)
        at = measured_at or utcnow()
        test_id = circles_repo.add_circular_test(
            s, machine_id, test, figures=figures, agreement=agreement,
            decision={a: d for a, d in decisions.items()}, measured_at=at, recorded_by=by)
        alerts: list[AlertRecord] = []
        for name, d in sorted(decisions.items(), key=lambda kv: axes[kv[0]].id):  # (locks in one order)
            if d is not None:
                alerts += circles_repo.update_alerts(s, axes[name].id, test_id, d.to_dict(), at=at)
        record = circles_repo.get_circular_test(s, test_id)
    out = StoredCircle(record, tuple(alerts), decisions, axes)
    _publish(svc, out)
    return out


def _publish(svc, stored: StoredCircle) -> None:
    now = utcnow()
    for name, axis in stored.axes.items():
        if svc.status is not None:
            svc.status.invalidate(axis.id)
        svc.events.publish(Event("circular_test_stored", axis.id, axis.machine_name, name, now))
    by_axis = {a.id: a for a in stored.axes.values()}
    for alert in stored.alerts:
        axis = by_axis[alert.axis_id]
        svc.events.publish(Event("alert_changed", axis.id, axis.machine_name, axis.name, now, alert=alert))
    for name, d in stored.decisions.items():
        if d is None:
            continue
        axis = stored.axes[name]
        # (the loop logs its own failures: the test is stored whatever the maintenance step does)
        svc.maintenance.after_circle(axis, stored.record, d, [a for a in stored.alerts if a.axis_id == axis.id])


def axis_summary(record: CircularTestRecord | None, axis: str) -> dict | None:
    """What the status body, MTConnect and OPC UA show of an axis' newest circular test:
    G and H with their U, the axis' largest reversal spike with its U (the measured TBE),
    the agreement with Eq. 8 at b̄ and the decision. None without a test."""
    if record is None or axis not in record.plane:
        return None
    fig = record.figures or {}
    spikes = [sp for sp in fig.get("spikes") or () if sp.get("axis") == axis and sp.get("height_um") is not None]
    spike = max(spikes, key=lambda sp: sp["height_um"]) if spikes else None
    ag = record.agreement.get(axis) or {}
    d = record.decision.get(axis) or {}
    return {
        "id": record.id, "measured_at": record.measured_at, "plane": list(record.plane),
        "radius_mm": record.radius_mm, "feed_mm_min": record.feed_mm_min,
        "circular_deviation_um": fig.get("circular_deviation_um"),
        "circular_deviation_uncertainty_um": fig.get("circular_deviation_uncertainty_um"),
        "hysteresis_um": fig.get("hysteresis_um"), "hysteresis_uncertainty_um": fig.get("hysteresis_uncertainty_um"),
        "spike_um": spike["height_um"] if spike else None,
        "spike_uncertainty_um": spike.get("height_uncertainty_um") if spike else None,
        "spike_at": f"{spike['direction']}@{spike['quadrant_deg']:g}°" if spike else None,
        "agreement": ag.get("verdict"), "normalised_error": ag.get("normalised_error"),
        "predicted_tbe_um": ag.get("predicted_um"), "predicted_tbe_uncertainty_um": ag.get("predicted_uncertainty_um"),
        "state": d.get("state"), "task": d.get("task"),
        "href": f"/api/v1/circles/{record.id}",
    }


def import_circular_test(csv_bytes: bytes, filename: str, profile_toml: bytes, **overrides) -> CircularTest:
    """The circular test of an exported CSV (a ballbar's or a trace tool's) read through a
    circle-import profile (TOML, acquisition.circle_import); ``overrides``: radius_mm,
    feed_mm_min, plane, temperature_c, utility_day (None: the profile's). Errors name the
    uploaded file's name, line and column, never the server's folders."""
    import re
    import tempfile
    import tomllib
    from pathlib import Path

    from acquisition.circle_import import parse_profile, read_circle

    try:
        doc = tomllib.loads(profile_toml.decode("utf-8"))
    except (UnicodeDecodeError, tomllib.TOMLDecodeError) as exc:
        raise InputError(f"profile: not a TOML circle-import profile ({exc})") from None
    profile = parse_profile(doc, "profile")
    name = re.sub(r"[^A-Za-z0-9_.-]+", "_", Path(filename or "").name).strip("._") or "circle.csv"
    with tempfile.TemporaryDirectory(prefix="mebm-circle-") as tmp:
        path = Path(tmp) / name
        path.write_bytes(csv_bytes)
        try:
            return read_circle(path, profile, **overrides)
        except InputError as exc:
            raise InputError(str(exc).replace(f"{tmp}/", "")) from None
