"""Frozen records the repository returns next to core types (ids, times, states).

Physical content is carried by core types: :class:`core.dataset.AxisSpec`,
:class:`core.tbe.MachiningTask`, :class:`core.criteria.RoundTripResult`,
:class:`core.tbe.AxisDecision`. Times are timezone-aware UTC.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from datetime import datetime, timezone

from core.circle.test import CircularTest
from core.criteria import RoundTripResult
from core.criteria.uncertainty import Instruments
from core.dataset import AxisSpec
from core.errors import InputError
from core.tbe import AxisDecision, MachiningTask

CYCLE_STATES = ("queued", "running", "ok", "failed", "interrupted", "cancelled")
TRIGGERS = ("schedule", "manual", "catch_up", "recovered", "verification")  # verification: after a repair
ROLES = ("read", "operate", "admin")


def utcnow() -> datetime:
    return datetime.now(timezone.utc)


def as_utc(t: datetime | None) -> datetime | None:
    """SQLite hands back naive datetimes: they were written as UTC."""
    if t is None:
        return None
    return t.replace(tzinfo=timezone.utc) if t.tzinfo is None else t.astimezone(timezone.utc)


@dataclass(frozen=True)
class Schedule:
    """Every ``interval_s`` seconds, or on a cron expression (5 fields, UTC); not both."""

    interval_s: float | None = None
    cron: str | None = None
    enabled: bool = True

    def __post_init__(self) -> None:
        if self.interval_s is not None and self.cron is not None:
            raise InputError("schedule: give interval_s or cron, not both")
        if self.interval_s is not None and not (self.interval_s >= 1.0 and self.interval_s < 1e9):
            raise InputError(f"schedule: interval_s (={self.interval_s}) must be >= 1 s")
        if self.cron is not None and len(self.cron.split()) != 5:
            raise InputError(f"schedule: cron (={self.cron!r}) must have 5 fields: minute hour day month weekday")

    @property
    def active(self) -> bool:
        return self.enabled and (self.interval_s is not None or self.cron is not None)


@dataclass(frozen=True)
class MachineRecord:
    id: int
    name: str
    description: str
    axis_ids: tuple[int, ...]
    uuid: str = ""  # the identity beyond this database, recorded in its axes' dataset folders


@dataclass(frozen=True)
class AxisSettings:
    """Everything configurable about an axis (what ``create_axis`` takes)."""

    spec: AxisSpec
    controller_url: str
    measure_feed_mm_min: float = 2000.0
    measure_acceleration_mm_s2: float = 500.0
    warning_fraction: float = 0.9
    schedule: Schedule = field(default_factory=Schedule)
    decision_rule: str = "guarded"  # ISO 14253-1: "simple" or "guarded" (core.tbe.decision)
    worst_case_temperature_c: float = 30.0  # the prognosis' date is for b̄ at this shop temperature
    tasks: tuple[MachiningTask, ...] = ()
    in_service_since: datetime | None = None
    # the linear scale and the thermometer it is measured with, for the uncertainty budget
    instruments: Instruments = field(default_factory=Instruments)


@dataclass(frozen=True)
class AxisRecord:
    id: int
    machine_id: int
    machine_name: str
    settings: AxisSettings
    # identities beyond this database (ids repeat in another one): the owner recorded in
    # the axis' dataset folders ("" for a record not read from a database: no owner check)
    uuid: str = ""
    machine_uuid: str = ""

    @property
    def spec(self) -> AxisSpec:
        return self.settings.spec

    @property
    def name(self) -> str:
        return self.settings.spec.name

    @property
    def tasks(self) -> tuple[MachiningTask, ...]:
        return self.settings.tasks


@dataclass(frozen=True)
class CycleRecord:
    id: int
    uuid: str
    axis_id: int
    trigger: str
    requested_by: str | None
    status: str
    requested_at: datetime
    started_at: datetime | None
    finished_at: datetime | None
    failure_reason: str | None
    temperature_c: float | None
    utility_day: float | None
    uncertainty_um: float | None
    run_file: str | None
    backlash_mean_um: float | None = None
    state: str | None = None
    raw_run_lost: str | None = None  # why the raw run could not be kept anywhere (None: kept)


@dataclass(frozen=True)
class TbeRecord:
    task: MachiningTask
    tbe_um: float
    backlash_limit_um: float  # inf: the task never reaches its tolerance
    state: str
    tbe_uncertainty_um: float | None = None  # expanded, k = 2
    backlash_limit_uncertainty_um: float | None = None
    decision_rule: str | None = None
    reason: str | None = None


@dataclass(frozen=True)
class ResultRecord:
    """A stored analysed measurement. ``round_trip`` has curves only when asked for."""

    id: int
    cycle_id: int
    axis_id: int
    measured_at: datetime
    temperature_c: float | None
    utility_day: float | None
    uncertainty_um: float | None
    round_trip: RoundTripResult
    state: str | None
    binding_task: str | None
    backlash_limit_um: float | None
    message: str | None
    tbe: tuple[TbeRecord, ...]
    decision_rule: str | None = None


@dataclass(frozen=True)
class FinishedCycle:
    """A cycle as the service hands it to storage when it ends (ok or not).

    Saved in one transaction with its result; ``uuid`` makes the save idempotent
    (a spooled cycle replayed after a database outage is stored once).
    """

    uuid: str
    axis_id: int
    trigger: str
    status: str
    requested_at: datetime
    started_at: datetime | None
    finished_at: datetime
    requested_by: str | None = None
    failure_reason: str | None = None
    temperature_c: float | None = None
    utility_day: float | None = None
    uncertainty_um: float | None = None
    run_file: str | None = None
    round_trip: RoundTripResult | None = None
    decision: AxisDecision | None = None
    raw_run_lost: str | None = None


@dataclass(frozen=True)
class AlertRecord:
    id: int
    axis_id: int
    kind: str
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
    raised_by_circular_test_id: int | None = None  # the evidence, when a circular test raised it
    cleared_by_circular_test_id: int | None = None

    @property
    def active(self) -> bool:
        return self.cleared_at is None


@dataclass(frozen=True)
class KeyRecord:
    id: int
    name: str
    role: str
    key_prefix: str
    created_at: datetime
    revoked_at: datetime | None


@dataclass(frozen=True)
class TrendSeries:
    """One point per ok measurement, oldest first. Lead criteria of the positive stroke."""

    measurement_id: tuple[int, ...]
    measured_at: tuple[datetime, ...]
    temperature_c: tuple[float | None, ...]
    utility_day: tuple[float | None, ...]
    backlash_mean_um: tuple[float, ...]
    e_p_um_per_1000mm: tuple[float, ...]
    v_u_um: tuple[float, ...]
    v_300_um: tuple[float, ...]
    v_2pi_um: tuple[float, ...]


@dataclass(frozen=True)
class TrendView:
    """The trend of a range: the points shown (a min/max downsampling of b̄, or all),
    how many measurements the range holds, and the moment sums over all of them
    (``stats[driver][criterion]``, core.history.MomentSums) for the correlations and the
    thermal model."""

    series: TrendSeries
    points_total: int
    stats: dict


@dataclass(frozen=True)
class TransitionRecord:
    id: int
    at: datetime
    from_state: str | None
    to_state: str
    by: str
    note: str
    figures: dict | None


@dataclass(frozen=True)
class RepairRecord:
    id: int
    axis_id: int
    order_id: int | None
    kind: str
    note: str
    performed_at: datetime
    recorded_at: datetime
    recorded_by: str
    compensation_measurement_id: int | None  # the cycle whose table was loaded (compensation_loaded)
    compensation_file: str | None
    before_measurement_id: int | None  # the last ok measurement before the repair


@dataclass(frozen=True)
class WorkOrderRecord:
    """A maintenance order (core.maintenance) with its transitions and repairs."""

    id: int
    axis_id: int
    kind: str
    state: str
    opened_at: datetime
    opened_by_measurement_id: int | None
    alert_id: int | None
    binding_task: str | None
    tolerance_um: float | None
    backlash_um: float | None
    backlash_uncertainty_um: float | None
    tbe_um: float | None
    tbe_uncertainty_um: float | None
    backlash_limit_um: float | None
    restore_below_um: float | None
    due_at: datetime | None
    recommendation: str
    verification_measurement_id: int | None
    verification: dict | None
    closed_at: datetime | None
    transitions: tuple[TransitionRecord, ...] = ()
    repairs: tuple[RepairRecord, ...] = ()
    opened_by_circular_test_id: int | None = None  # the evidence, when a circular test's decision opened it

    @property
    def active(self) -> bool:
        return self.state in ("open", "acknowledged", "repaired")


@dataclass(frozen=True)
class OrderRequest:
    """What the service asks storage to open: the recommendation's figures."""

    axis_id: int
    kind: str
    opened_at: datetime
    recommendation: str
    result_id: int | None = None
    alert_id: int | None = None
    binding_task: str | None = None
    tolerance_um: float | None = None
    backlash_um: float | None = None
    backlash_uncertainty_um: float | None = None
    tbe_um: float | None = None
    tbe_uncertainty_um: float | None = None
    backlash_limit_um: float | None = None
    restore_below_um: float | None = None
    due_at: datetime | None = None
    circular_test_id: int | None = None  # the circular test whose decision opened it (instead of result_id)


@dataclass(frozen=True)
class CircularTestRecord:
    """A stored circular test (ISO 230-4): ``test`` is the core.circle CircularTest with its
    samples (None in a list read without them); ``figures`` is CircleFigures.to_dict();
    ``agreement`` and ``decision`` are per axis name of the plane (Agreement.to_dict(),
    CircleDecision.to_dict() or None when no circle task of that axis matched the test);
    ``state`` is the worst judged state (None: no task judged)."""

    id: int
    machine_id: int
    machine_name: str
    plane: tuple[str, str]
    axis_ids: tuple[int | None, int | None]
    radius_mm: float
    feed_mm_min: float
    directions: tuple[str, ...]
    temperature_c: float | None
    utility_day: float | None
    measured_at: datetime
    recorded_at: datetime
    recorded_by: str | None
    source: str
    instrument: dict
    figures: dict | None
    agreement: dict[str, dict]
    decision: dict[str, dict | None]
    state: str | None
    test: CircularTest | None = None  # with its samples (get), None in a list

    def axis_id_of(self, name: str) -> int | None:
        return self.axis_ids[self.plane.index(name)] if name in self.plane else None
