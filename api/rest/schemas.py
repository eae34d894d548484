"""Pydantic schemas of the REST API (separate from the ORM models). Units in every name."""

from __future__ import annotations

import math
from datetime import datetime
from typing import Any, Literal

from pydantic import BaseModel, Field

# the configuration bodies are the service's: the dashboard's forms validate with them too
from api.service.config.input import (  # noqa: F401
    MAX_PROGRAM_MIN,
    MAX_TRAVEL_MM,
    AxisIn,
    In,
    MachineIn,
    ScheduleIn,
    TaskIn,
    TasksIn,
    link_local_problem,
)

Finite = dict(allow_inf_nan=False)


def fin(x: float | None) -> float | None:
    """JSON has no infinity: an unbounded limit is null."""
    return None if x is None or not math.isfinite(x) else float(x)


# -- machines and axes ---------------------------------------------------------------------------


class MachineOut(BaseModel):
    id: int
    name: str
    description: str
    axis_ids: list[int]


class TaskOut(BaseModel):
    name: str
    profile: str
    feed_mm_min: float
    tolerance_um: float
    gain_per_s: float
    radius_mm: float | None
    angle_deg: float | None
    backlash_limit_um: float | None = Field(description="largest permissible mean backlash; null: no limit")


class ScheduleOut(BaseModel):
    interval_s: float | None
    cron: str | None
    enabled: bool
    next_run_at: datetime | None


class AxisOut(BaseModel):
    id: int
    machine_id: int
    machine_name: str
    name: str
    transmission_mm_per_rev: float
    screw_lead_mm: float
    position_gain_per_s: float
    travel_mm: tuple[float, float]
    controller_url: str
    measure_feed_mm_min: float
    measure_acceleration_mm_s2: float
    warning_fraction: float
    decision_rule: str = "guarded"
    worst_case_temperature_c: float = 30.0
    scale_accuracy_um: float = Field(1.0, description="the linear scale's short-range accuracy, ± µm (budget)")
    scale_accuracy_um_per_m: float = Field(5.0, description="the linear scale's accuracy class, ± µm per metre")
    thermometer_class: str = Field("B", description="IEC 60751 class of the Pt100 thermometer")
    thermal_expansion_per_k: float = Field(11.5e-6, description="the axis' thermal expansion coefficient, 1/K")
    schedule: ScheduleOut
    tasks: list[TaskOut]


# -- status ----------------------------------------------------------------------------------------
class TaskStatus(BaseModel):
    name: str
    profile: str
    tolerance_um: float
    warning_threshold_um: float
    tbe_um: float
    tbe_uncertainty_um: float = Field(0.0, description="expanded (k = 2), from b̄'s through Eq. 7/8")
    backlash_limit_um: float | None
    backlash_limit_uncertainty_um: float | None = Field(None, description="expanded (k = 2), from the gain")
    state: Literal["OK", "WARNING", "ALARM"]
    decision_rule: Literal["simple", "guarded"] = "guarded"
    reason: str = ""
    utilisation: float = Field(description="TBE / tolerance")


class AxisStatusOut(BaseModel):
    axis_id: int
    machine_id: int
    machine_name: str
    axis_name: str
    state: Literal["OK", "WARNING", "ALARM", "UNKNOWN"]
    message: str
    measurement_id: int | None
    measured_at: datetime | None
    age_s: float | None = Field(description="age of the last good measurement, seconds")
    temperature_c: float | None
    utility_day: float | None
    backlash_mean_um: float | None
    backlash_mean_20c_um: float | None = Field(description="b̄ normalised to 20 °C with the axis' thermal model")
    thermal_beta_um_per_k: float | None
    uncertainty_um: float | None = Field(description="combined standard uncertainty of b̄ (GUM)")
    backlash_mean_uncertainty_um: float | None = Field(None, description="expanded (k = 2) uncertainty of b̄")
    e_p_uncertainty_um: float | None = None
    v_u_uncertainty_um: float | None = None
    v_300_uncertainty_um: float | None = None
    v_2pi_uncertainty_um: float | None = None
    outliers_removed: int | None = None
    backlash_mean_20c_uncertainty_um: float | None = Field(
        None, description="expanded (k = 2) uncertainty of b̄ at 20 °C: b̄'s budget plus the normalisation (β, thermometer)")
    uncertainty_budget: dict[str, Any] | None = Field(
        None, description="the GUM budgets of b̄ (and of b̄ at 20 °C) and of the positive stroke's lead criteria "
                          "(positive.e_p, ...): each component's standard_um and its note (why, also when 0)")
    reversal_mean_um: float | None = Field(None, description="ISO 230-2 mean reversal value B̄ (lost motion), µm")
    reversal_max_um: float | None = Field(None, description="ISO 230-2 reversal value B = max |B_i|, µm")
    lost_motion: dict[str, Any] | None = Field(
        None, description="B_i at the targets, the clearance estimate from the program's feeds and from the "
                          "history's, and the TBE's basis (the total lost motion)")
    prognosis: dict[str, Any] | None = Field(
        None, description="GET /axes/{id}/prognosis: the ALARM temperature, the date the worst-case b̄ reaches "
                          "the backlash limit, or why the history does not support the fit")
    decision_rule: Literal["simple", "guarded"] | None = None
    backlash_limit_um: float | None
    restore_below_um: float | None = Field(
        None, description="the mean backlash a repair must restore the chain below: the warning level in backlash "
                          "(backlash limit × warning fraction); null: no task limits the backlash")
    restore_below_explanation: str | None = Field(None, description="why the repair target is that figure")
    backlash_reduction_needed_um: float | None = Field(
        description="how much the mean backlash must be reduced to get below the limit (0 when below)")
    binding_task: str | None
    tasks: list[TaskStatus]
    active_alert_id: int | None
    last_cycle_status: str | None
    last_cycle_at: datetime | None
    last_failure_reason: str | None
    last_raw_run_lost: str | None = Field(
        None, description="why the raw run of the last finished cycle could not be kept (null: it was kept)")
    circular_test: dict[str, Any] | None = Field(
        None, description="the axis' newest circular test (ISO 230-4), beside the TBE: G and H with U, the axis' "
                          "largest reversal spike with U (the measured TBE), its agreement with Eq. 8 at b̄, the "
                          "decision on the task at the test's radius and feed; href: GET /circles/{id}")
    work_order: dict[str, Any] | None = Field(
        None, description="the axis' active maintenance order (null: none): id, kind, state, opened_at, due_at, "
                          "restore_below_um, recommendation and its link; GET /maintenance/orders/{id} has the rest")
    next_run_at: datetime | None


# -- measurements ------------------------------------------------------------------------------------
class MeasurementSummary(BaseModel):
    id: int
    axis_id: int
    status: str
    trigger: str
    requested_by: str | None
    requested_at: datetime
    started_at: datetime | None
    finished_at: datetime | None
    failure_reason: str | None
    reason_code: str | None = Field(None, description="machine-readable reason: storage_full (no room under the "
                                    "data folder; failure_reason says what to free), or null")
    temperature_c: float | None
    utility_day: float | None
    uncertainty_um: float | None
    backlash_mean_um: float | None
    state: str | None
    raw_run_lost: str | None = Field(None, description="why the raw run could not be kept (null: it was kept)")


class MeasurementPage(BaseModel):
    items: list[MeasurementSummary]
    total: int
    limit: int
    offset: int


class LeadOut(BaseModel):
    direction: str
    e_p_um: float
    e_p_um_per_1000mm: float
    v_u_um: float
    v_300_um: float
    v_2pi_um: float
    n_strokes: int


class TbeOut(BaseModel):
    task_name: str
    profile: str
    tolerance_um: float
    tbe_um: float
    backlash_limit_um: float | None
    state: str


class CurvesOut(BaseModel):
    position_mm: list[float]
    backlash_um: list[float]
    positive_travel_deviation_um: list[float]
    negative_travel_deviation_um: list[float]
    positive_mean_travel_deviation_um: list[float]
    negative_mean_travel_deviation_um: list[float]


class ResultOut(BaseModel):
    backlash_mean_um: float
    backlash_min_um: float
    backlash_max_um: float
    backlash_std_um: float
    useful_travel_mm: tuple[float, float]
    n_samples: int
    peak_speed_mm_min: float
    lead: dict[str, LeadOut]
    tbe: list[TbeOut]
    state: str | None
    binding_task: str | None
    backlash_limit_um: float | None
    message: str | None
    run_file: str | None


class MeasurementDetail(MeasurementSummary):
    result: ResultOut | None
    curves: CurvesOut | None


class TriggerOut(BaseModel):
    measurement: MeasurementSummary | None
    uuid: str
    queued: bool
    detail: str


# -- trend ---------------------------------------------------------------------------------------------
class TrendSeriesOut(BaseModel):
    measurement_id: list[int]
    measured_at: list[datetime]
    temperature_c: list[float | None]
    utility_day: list[float | None]
    backlash_mean_um: list[float]
    e_p_um_per_1000mm: list[float]
    v_u_um: list[float]
    v_300_um: list[float]
    v_2pi_um: list[float]


class ThermalModelOut(BaseModel):
    backlash_20c_um: float
    beta_um_per_k: float
    r: float | None
    n: int


class TrendOut(BaseModel):
    axis_id: int
    points: int = Field(description="points in the series (at most max_points: min and max of b̄ per bucket)")
    points_total: int = Field(description="measurements in the time range (correlation and thermal model use all)")
    series: TrendSeriesOut
    correlation: dict[str, dict[str, float | None]] = Field(
        description="Pearson r (Eq. 4) of each criterion against temperature_c and utility_day; null if undefined")
    thermal_model: ThermalModelOut | None


# -- alerts and keys -------------------------------------------------------------------------------------
class AlertOut(BaseModel):
    id: int
    axis_id: int
    kind: str
    active: bool
    raised_at: datetime
    cleared_at: datetime | None
    acknowledged_at: datetime | None
    acknowledged_by: str | None
    raised_by_measurement_id: int | None
    cleared_by_measurement_id: int | None
    task_name: str | None
    tbe_um: float | None
    tolerance_um: float | None
    backlash_um: float | None
    backlash_limit_um: float | None
    message: str
    raised_by_circular_test_id: int | None = Field(
        None, description="the circular test whose decision raised it (GET /circles/{id}); null: a measurement's")
    cleared_by_circular_test_id: int | None = None


class AlertPage(BaseModel):
    items: list[AlertOut]
    total: int
    limit: int
    offset: int


class KeyIn(In):
    name: str = Field(min_length=1, max_length=100, pattern=r"\S", description="not blank")
    role: Literal["read", "operate", "admin"]


class KeyOut(BaseModel):
    id: int
    name: str
    role: str
    key_prefix: str
    created_at: datetime
    revoked_at: datetime | None


class KeyCreated(KeyOut):
    key: str = Field(description="the secret; shown once, stored only hashed")


class FieldError(BaseModel):
    field: str
    message: str


class ErrorOut(BaseModel):
    """Every error answer: ``detail`` says what is wrong (and names the field for 422)."""

    detail: str
    errors: list[FieldError] | None = None


ERROR_RESPONSES = {
    401: {"model": ErrorOut, "description": "no key, or an unknown or revoked key"},
    403: {"model": ErrorOut, "description": "the key's role does not allow this"},
    404: {"model": ErrorOut, "description": "unknown id"},
    409: {"model": ErrorOut, "description": "conflicts with what is stored"},
    413: {"model": ErrorOut, "description": "request body larger than limits.max_body_bytes"},
    422: {"model": ErrorOut, "description": "invalid input; the message names the field"},
    429: {"model": ErrorOut, "description": "too many failed authentications from this address, too many "
                                            "triggers for this key, or a manual measurement waits already; "
                                            "see Retry-After"},
    503: {"model": ErrorOut, "description": "database unavailable; retry later"},
}


class Health(BaseModel):
    status: Literal["ok", "degraded"]
    database: Literal["ok", "read-only", "unavailable"]
    data_dir: Literal["ok", "not writable"]
    free_disk_mb: float | None
    problems: list[str] = Field(description="why the status is degraded, one line each (empty when ok)")
    version: str
    uptime_s: float
    spooled_cycles: int
    opcua: str | None = Field(None, description="the OPC UA server: 'listening on <endpoint>', or why it is off "
                                                "(it never makes the service degraded); null when not configured")
