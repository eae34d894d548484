"""The dashboard's configuration forms (machines, axes, machining tasks, schedules).

A form's fields are read into the same pydantic models as the REST API's request bodies
(``api.service.config.input``), then built into stored settings by the same functions:
one validation for both. Errors come back keyed by field (``name``, ``tasks.2.radius_mm``,
``cron``; ``""`` for the form as a whole) so the template puts each next to its field.
"""

from __future__ import annotations

import re
from collections.abc import Mapping
from dataclasses import dataclass, field

from pydantic import BaseModel, ValidationError

from api.service.config.input import AxisIn, MachineIn, ScheduleIn, TaskIn, TasksIn

TASK_FIELDS = ("name", "profile", "feed_mm_min", "tolerance_um", "radius_mm", "angle_deg")
AXIS_FIELDS = ("name", "transmission_mm_per_rev", "screw_lead_mm", "position_gain_per_s", "travel_start_mm",
               "travel_end_mm", "controller_url", "measure_feed_mm_min", "measure_acceleration_mm_s2",
               "warning_fraction", "decision_rule", "worst_case_temperature_c", "interval_s", "cron")
MAX_TASK_ROWS = 51  # TasksIn takes 50; one more row lets the form say so


@dataclass
class Checked:
    """A validated body (``value``) or the errors by field, and the form as sent (to refill it)."""

    value: BaseModel | None
    errors: dict[str, str] = field(default_factory=dict)
    form: dict = field(default_factory=dict)


def _text(form: Mapping, name: str) -> str:
    v = form.get(name, "")
    return v.strip() if isinstance(v, str) else ""


def _put(d: dict, key: str, raw: str) -> None:
    if raw != "":  # an empty optional field is absent: the model's default or None applies
        d[key] = raw


PATTERN_HINTS = {  # a regular expression is no message for a person
    "name": "letters, digits, spaces and . _ - only, starting with a letter or digit",
    "axis.name": "lower-case letters, digits and _ only, starting with a letter (x, y, z, b2)",
    "controller_url": "sim, modbus://host:port, modbus+rtu://serial-device or canopen://interface/node",
}


def field_errors(exc: ValidationError, rename: Mapping[str, str] | None = None, kind: str = "") -> dict[str, str]:
    out: dict[str, str] = {}
    for e in exc.errors():
        loc = ".".join(str(p) for p in e["loc"])
        msg = e["msg"].removeprefix("Value error, ")
        if e["type"] == "string_pattern_mismatch":
            msg = PATTERN_HINTS.get(f"{kind}.{loc}", PATTERN_HINTS.get(loc, msg))
        elif e["type"] == "float_parsing":
            msg = f"{e['input']!r} is not a number"
        elif e["type"] == "missing" or (e["type"] == "float_type" and e.get("input") is None):
            msg = "required"
        if not loc:  # a rule over several fields: put it by the field it names, if any
            loc = next((f for f in (rename or {}) if re.search(rf"\b{f}\b", msg)), "")
        loc = (rename or {}).get(loc, loc)
        if loc == "schedule" or loc.startswith("schedule."):
            loc = loc.removeprefix("schedule").lstrip(".") or "cron"
        out.setdefault(loc, msg)
    return out


def machine(form: Mapping) -> Checked:
    sent = {"name": _text(form, "name"), "description": _text(form, "description")}
    try:
        return Checked(MachineIn(**sent), form=sent)
    except ValidationError as exc:
        return Checked(None, field_errors(exc), sent)


def schedule(form: Mapping) -> Checked:
    sent = {"interval_s": _text(form, "interval_s"), "cron": _text(form, "cron"),
            "enabled": form.get("enabled") == "on"}
    body: dict = {"enabled": sent["enabled"]}
    _put(body, "interval_s", sent["interval_s"])
    _put(body, "cron", sent["cron"])
    try:
        return Checked(ScheduleIn(**body), form=sent)
    except ValidationError as exc:
        errs = field_errors(exc)
        if "" in errs:  # "give interval_s or cron, not both"
            errs.setdefault("cron", errs.pop(""))
        return Checked(None, errs, sent)


def task_rows(form: Mapping) -> list[dict]:
    """The task rows of the form, as sent (``rows`` of them; a blank row adds nothing)."""
    try:
        n = min(int(_text(form, "rows") or 0), MAX_TASK_ROWS)
    except ValueError:
        n = 0
    rows = []
    for i in range(n):
        row = {f: _text(form, f"{f}_{i}") for f in TASK_FIELDS}
        row["remove"] = form.get(f"remove_{i}") == "on"
        rows.append(row)
    return rows


def tasks(form: Mapping) -> tuple[Checked, list[int]]:
    """The tasks to keep (rows neither blank nor marked for removal) and, for each, its
    row in the form (an error at ``tasks.3`` of the body is shown on that row)."""
    rows = task_rows(form)
    kept, where = [], []
    for i, row in enumerate(rows):
        if row["remove"] or not any(row[f] for f in TASK_FIELDS if f != "profile"):
            continue
        body: dict = {}
        for f in TASK_FIELDS:
            _put(body, f, row[f])
        kept.append(body)
        where.append(i)
    try:
        return Checked(TasksIn(tasks=kept), form={"rows": rows}), where
    except ValidationError as exc:
        errs: dict[str, str] = {}
        for k, v in field_errors(exc).items():
            m = re.match(r"tasks\.(\d+)(?:\.(\w+))?$", k)
            if m:
                errs.setdefault(f"tasks.{where[int(m.group(1))]}" + (f".{m.group(2)}" if m.group(2) else ""), v)
            else:
                errs.setdefault("", "keep at least one machining task (an axis without one has no verdict)"
                                if k == "tasks" and not kept else f"{k}: {v}")
        return Checked(None, errs, {"rows": rows}), where


def axis(form: Mapping) -> Checked:
    sent = {f: _text(form, f) for f in AXIS_FIELDS}
    sent["enabled"] = form.get("enabled") == "on"
    body: dict = {"schedule": {"enabled": sent["enabled"]}, "tasks": []}
    for f in AXIS_FIELDS:
        if f in ("interval_s", "cron"):
            _put(body["schedule"], f, sent[f])
        elif f not in ("travel_start_mm", "travel_end_mm"):
            _put(body, f, sent[f])
    body["travel_mm"] = (sent["travel_start_mm"] or None, sent["travel_end_mm"] or None)
    try:
        return Checked(AxisIn(**body), form=sent)
    except ValidationError as exc:
        errs = field_errors(exc, rename={"travel_mm": "travel_end_mm", "travel_mm.0": "travel_start_mm",
                                    "travel_mm.1": "travel_end_mm", "measure_feed_mm_min": "measure_feed_mm_min"},
                       kind="axis")
        return Checked(None, errs, sent)


def new_task_row() -> dict:
    return {**{f: "" for f in TASK_FIELDS}, "profile": "circle", "remove": False}


def row_of(t) -> dict:
    """A form row from a stored MachiningTask."""
    def num(v):
        return "" if v is None else f"{v:g}"

    return {"name": t.name, "profile": t.profile, "feed_mm_min": num(t.feed_mm_min),
            "tolerance_um": num(t.tolerance_um), "radius_mm": num(t.radius_mm if t.profile == "circle" else None),
            "angle_deg": num(t.angle_deg if t.profile == "line" else None), "remove": False}


__all__ = ["Checked", "TaskIn", "axis", "machine", "new_task_row", "row_of", "schedule", "task_rows", "tasks"]
