"""What a person sends to the maintenance loop, validated once for every
writer: the REST API's request bodies (``api.rest.routers.maintenance``) and the
dashboard's forms (``api.ui.maintenance``) both read into these models, so a value
refused by one is refused by the other with the same message. Also the managers'
summary as CSV, written the same way for ``GET /api/v1/maintenance/summary?format=csv``
and the dashboard's download.
"""

from __future__ import annotations

import csv
import io
from datetime import datetime, timezone
from typing import Annotated, Literal

from pydantic import AfterValidator, BaseModel, Field

from core.maintenance import REPAIR_KINDS


def utc(t: datetime | None) -> datetime | None:
    """An aware UTC time (a naive one is taken as UTC)."""
    if t is None:
        return None
    return t.replace(tzinfo=timezone.utc) if t.tzinfo is None else t.astimezone(timezone.utc)


class NoteIn(BaseModel):
    note: str = Field("", max_length=4000, description="why (required to cancel)")


class RepairIn(BaseModel):
    kind: Literal[REPAIR_KINDS] = Field(description="what was done")  # type: ignore[valid-type]
    note: str = Field("", max_length=4000, description="free text: what, which parts, readings")
    performed_at: Annotated[datetime | None, AfterValidator(utc)] = Field(
        None, description="when it was done (ISO 8601; default: now)")
    compensation_measurement_id: int | None = Field(
        None, ge=1, le=2**31 - 1, description="compensation_loaded: the measurement whose table was loaded "
                                              "(the X-Measurement-Id of GET /axes/{id}/compensation; default: the "
                                              "newest before the repair)")
    compensation_file: str | None = Field(None, max_length=300, description="the table's file name, for the record")


SUMMARY_COLUMNS = ("machine", "axis", "axis_id", "history_days", "repairs_called_by_error", "repairs_other",
                   "orders_opened", "orders_verified", "orders_corrective", "orders_condition_based",
                   "interval_mean_days", "interval_min_days", "alarm_to_verified_mean_days",
                   "alarm_to_verified_max_days", "fixed_interval_days", "fixed_interval_repairs", "repairs_saved",
                   "repairs_saved_note")


def summary_rows(axes: list) -> list[dict]:
    """``MaintenanceLoop.summary``'s per-axis part as flat rows (machine and axis names first)."""
    return [{"machine": a.machine_name, "axis": a.name, **x.to_dict()} for a, x in axes]


def summary_csv(rows: list[dict], fleet: dict) -> str:
    """One row per axis and a last ``(fleet)`` row, the columns of :data:`SUMMARY_COLUMNS`."""
    buf = io.StringIO()
    w = csv.DictWriter(buf, fieldnames=SUMMARY_COLUMNS, extrasaction="ignore", lineterminator="\n")
    w.writeheader()
    w.writerows(rows)
    w.writerow({"machine": "(fleet)", "axis": "", "axis_id": "", **{k: v for k, v in fleet.items()
                                                                      if k in SUMMARY_COLUMNS}})
    return buf.getvalue()
