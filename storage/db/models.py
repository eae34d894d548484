"""ORM models (SQLAlchemy 2.x, typed). Units are in the column names.

These are the storage layer's private shapes: the repository turns them into core
types and the frozen records of :mod:`storage.db.records`; the API never sees them.
Times are UTC.
"""

from __future__ import annotations

from datetime import datetime

from sqlalchemy import (
    Boolean,
    DateTime,
    Float,
    ForeignKey,
    Index,
    Integer,
    LargeBinary,
    String,
    Text,
    UniqueConstraint,
    text,
)
from sqlalchemy.orm import DeclarativeBase, Mapped, mapped_column, relationship


class Base(DeclarativeBase):
    pass


UtcDateTime = DateTime(timezone=True)


class Machine(Base):
    __tablename__ = "machines"

    id: Mapped[int] = mapped_column(primary_key=True)
    name: Mapped[str] = mapped_column(String(100), unique=True)
    # the machine's identity beyond this database (ids repeat in another one): recorded
    # as the owner of its axes' dataset folders. Set on creation and by the migration.
    uuid: Mapped[str | None] = mapped_column(String(36), unique=True, index=True, nullable=True)
    description: Mapped[str] = mapped_column(Text, default="")
    created_at: Mapped[datetime] = mapped_column(UtcDateTime)

    axes: Mapped[list[Axis]] = relationship(back_populates="machine", order_by="Axis.id")


class Axis(Base):
    """A monitored axis: its mechanics (k_a, lead, travel, K), where its controller is,
    how it is measured (round-trip feed) and when (interval or cron schedule)."""

    __tablename__ = "axes"
    __table_args__ = (UniqueConstraint("machine_id", "name"),)

    id: Mapped[int] = mapped_column(primary_key=True)
    machine_id: Mapped[int] = mapped_column(ForeignKey("machines.id", ondelete="CASCADE"), index=True)
    name: Mapped[str] = mapped_column(String(20))
    uuid: Mapped[str | None] = mapped_column(String(36), unique=True, index=True, nullable=True)  # as Machine.uuid
    transmission_mm_per_rev: Mapped[float] = mapped_column(Float)
    screw_lead_mm: Mapped[float] = mapped_column(Float)
    position_gain_per_s: Mapped[float] = mapped_column(Float)
    travel_start_mm: Mapped[float] = mapped_column(Float)
    travel_end_mm: Mapped[float] = mapped_column(Float)
    controller_url: Mapped[str] = mapped_column(String(300))
    measure_feed_mm_min: Mapped[float] = mapped_column(Float)
    measure_acceleration_mm_s2: Mapped[float] = mapped_column(Float)
    warning_fraction: Mapped[float] = mapped_column(Float)
    decision_rule: Mapped[str] = mapped_column(String(10), default="guarded", server_default="guarded")
    # the shop's worst-case temperature for the prognosis (None: the default, AxisSettings)
    worst_case_temperature_c: Mapped[float | None] = mapped_column(Float, nullable=True)
    # the instruments of the uncertainty budget (None: the default, core.criteria.uncertainty.Instruments)
    scale_accuracy_um: Mapped[float | None] = mapped_column(Float, nullable=True)
    scale_accuracy_um_per_m: Mapped[float | None] = mapped_column(Float, nullable=True)
    thermometer_class: Mapped[str | None] = mapped_column(String(4), nullable=True)
    thermal_expansion_per_k: Mapped[float | None] = mapped_column(Float, nullable=True)
    schedule_interval_s: Mapped[float | None] = mapped_column(Float, nullable=True)
    schedule_cron: Mapped[str | None] = mapped_column(String(120), nullable=True)
    schedule_enabled: Mapped[bool] = mapped_column(Boolean, default=True)
    in_service_since: Mapped[datetime] = mapped_column(UtcDateTime)
    created_at: Mapped[datetime] = mapped_column(UtcDateTime)

    machine: Mapped[Machine] = relationship(back_populates="axes")
    tasks: Mapped[list[MachiningTaskRow]] = relationship(
        back_populates="axis", order_by="MachiningTaskRow.id", cascade="all, delete-orphan"
    )


class MachiningTaskRow(Base):
    """What the shop makes with the axis; the TBE is estimated for each (Eqs. 7-8)."""

    __tablename__ = "machining_tasks"
    __table_args__ = (UniqueConstraint("axis_id", "name"),)

    id: Mapped[int] = mapped_column(primary_key=True)
    axis_id: Mapped[int] = mapped_column(ForeignKey("axes.id", ondelete="CASCADE"), index=True)
    name: Mapped[str] = mapped_column(String(100))
    profile: Mapped[str] = mapped_column(String(10))
    radius_mm: Mapped[float | None] = mapped_column(Float, nullable=True)
    angle_deg: Mapped[float | None] = mapped_column(Float, nullable=True)
    feed_mm_min: Mapped[float] = mapped_column(Float)
    tolerance_um: Mapped[float] = mapped_column(Float)

    axis: Mapped[Axis] = relationship(back_populates="tasks")


ONE_WAITING_MANUAL = "status = 'queued' AND \"trigger\" = 'manual'"


class Cycle(Base):
    """One measurement cycle: queued -> running -> ok | failed | interrupted | cancelled.
    At most one manual cycle per axis waits (a partial unique index: the rule is atomic)."""

    __tablename__ = "cycles"
    __table_args__ = (
        Index("ix_cycles_axis_requested", "axis_id", "requested_at"),
        Index("uq_cycles_one_waiting_manual", "axis_id", unique=True,
              sqlite_where=text(ONE_WAITING_MANUAL), postgresql_where=text(ONE_WAITING_MANUAL)),
    )

    id: Mapped[int] = mapped_column(primary_key=True)
    uuid: Mapped[str] = mapped_column(String(36), unique=True)
    axis_id: Mapped[int] = mapped_column(ForeignKey("axes.id", ondelete="CASCADE"), index=True)
    trigger: Mapped[str] = mapped_column(String(20))
    requested_by: Mapped[str | None] = mapped_column(String(100), nullable=True)
    status: Mapped[str] = mapped_column(String(20), index=True)
    requested_at: Mapped[datetime] = mapped_column(UtcDateTime)
    started_at: Mapped[datetime | None] = mapped_column(UtcDateTime, nullable=True)
    finished_at: Mapped[datetime | None] = mapped_column(UtcDateTime, nullable=True)
    failure_reason: Mapped[str | None] = mapped_column(Text, nullable=True)
    temperature_c: Mapped[float | None] = mapped_column(Float, nullable=True)
    utility_day: Mapped[float | None] = mapped_column(Float, nullable=True)
    uncertainty_um: Mapped[float | None] = mapped_column(Float, nullable=True)
    run_file: Mapped[str | None] = mapped_column(String(200), nullable=True)
    raw_run_lost: Mapped[str | None] = mapped_column(Text, nullable=True)  # why the raw run was not kept
    # fleet: the worker that ran it (workers.id) and, for a scheduled one, when it was due
    worker: Mapped[str | None] = mapped_column(String(36), nullable=True)
    due_at: Mapped[datetime | None] = mapped_column(UtcDateTime, nullable=True)

    result: Mapped[Result | None] = relationship(back_populates="cycle", uselist=False)


class Result(Base):
    """The analysed round trip of an ok cycle: b̄ and profile statistics, the decision."""

    __tablename__ = "results"
    __table_args__ = (Index("ix_results_axis_measured", "axis_id", "measured_at"),)

    id: Mapped[int] = mapped_column(primary_key=True)
    cycle_id: Mapped[int] = mapped_column(ForeignKey("cycles.id", ondelete="CASCADE"), unique=True)
    axis_id: Mapped[int] = mapped_column(ForeignKey("axes.id", ondelete="CASCADE"))
    measured_at: Mapped[datetime] = mapped_column(UtcDateTime)
    temperature_c: Mapped[float | None] = mapped_column(Float, nullable=True)
    utility_day: Mapped[float | None] = mapped_column(Float, nullable=True)
    backlash_mean_um: Mapped[float] = mapped_column(Float)
    backlash_min_um: Mapped[float] = mapped_column(Float)
    backlash_max_um: Mapped[float] = mapped_column(Float)
    backlash_std_um: Mapped[float] = mapped_column(Float)
    useful_travel_start_mm: Mapped[float] = mapped_column(Float)
    useful_travel_end_mm: Mapped[float] = mapped_column(Float)
    n_samples: Mapped[int] = mapped_column(Integer)
    peak_speed_mm_min: Mapped[float] = mapped_column(Float)
    uncertainty_um: Mapped[float | None] = mapped_column(Float, nullable=True)
    state: Mapped[str | None] = mapped_column(String(10), nullable=True)
    binding_task: Mapped[str | None] = mapped_column(String(100), nullable=True)
    backlash_limit_um: Mapped[float | None] = mapped_column(Float, nullable=True)
    message: Mapped[str | None] = mapped_column(Text, nullable=True)
    # metrology of the result (NULL on results stored before migration 0002)
    backlash_mean_uncertainty_um: Mapped[float | None] = mapped_column(Float, nullable=True)  # expanded, k = 2
    outliers_removed: Mapped[int | None] = mapped_column(Integer, nullable=True)
    grid_step_mm: Mapped[float | None] = mapped_column(Float, nullable=True)
    noise_um: Mapped[float | None] = mapped_column(Float, nullable=True)
    uncertainty_budget: Mapped[str | None] = mapped_column(Text, nullable=True)  # JSON: the GUM budgets
    decision_rule: Mapped[str | None] = mapped_column(String(10), nullable=True)
    # ISO 230-2 lost motion: B̄, B, and JSON of B_i and the clearance estimate
    reversal_mean_um: Mapped[float | None] = mapped_column(Float, nullable=True)
    reversal_max_um: Mapped[float | None] = mapped_column(Float, nullable=True)
    lost_motion: Mapped[str | None] = mapped_column(Text, nullable=True)

    cycle: Mapped[Cycle] = relationship(back_populates="result")
    lead: Mapped[list[LeadCriteriaRow]] = relationship(order_by="LeadCriteriaRow.id", cascade="all, delete-orphan")
    curves: Mapped[list[Curve]] = relationship(cascade="all, delete-orphan")
    tbe: Mapped[list[TbeRow]] = relationship(order_by="TbeRow.id", cascade="all, delete-orphan")


class LeadCriteriaRow(Base):
    """ISO 3408-3 criteria of one stroke direction (Eqs. 1-3)."""

    __tablename__ = "lead_criteria"
    __table_args__ = (UniqueConstraint("result_id", "direction"),)

    id: Mapped[int] = mapped_column(primary_key=True)
    result_id: Mapped[int] = mapped_column(ForeignKey("results.id", ondelete="CASCADE"))
    direction: Mapped[str] = mapped_column(String(10))
    e_p_um: Mapped[float] = mapped_column(Float)
    e_p_um_per_1000mm: Mapped[float] = mapped_column(Float)
    v_u_um: Mapped[float] = mapped_column(Float)
    v_300_um: Mapped[float] = mapped_column(Float)
    v_2pi_um: Mapped[float] = mapped_column(Float)
    n_strokes: Mapped[int] = mapped_column(Integer)


class Curve(Base):
    """A curve on a uniform position grid, values as little-endian float32 (compact)."""

    __tablename__ = "curves"
    __table_args__ = (UniqueConstraint("result_id", "name"),)

    id: Mapped[int] = mapped_column(primary_key=True)
    result_id: Mapped[int] = mapped_column(ForeignKey("results.id", ondelete="CASCADE"))
    name: Mapped[str] = mapped_column(String(60))
    position_start_mm: Mapped[float] = mapped_column(Float)
    position_step_mm: Mapped[float] = mapped_column(Float)
    n_points: Mapped[int] = mapped_column(Integer)
    values_f32: Mapped[bytes] = mapped_column(LargeBinary)


class TbeRow(Base):
    """TBE of one machining task at the measured b̄, with the task as it was then."""

    __tablename__ = "tbe_results"
    __table_args__ = (Index("ix_tbe_result", "result_id"),)

    id: Mapped[int] = mapped_column(primary_key=True)
    result_id: Mapped[int] = mapped_column(ForeignKey("results.id", ondelete="CASCADE"))
    task_name: Mapped[str] = mapped_column(String(100))
    profile: Mapped[str] = mapped_column(String(10))
    radius_mm: Mapped[float | None] = mapped_column(Float, nullable=True)
    angle_deg: Mapped[float | None] = mapped_column(Float, nullable=True)
    feed_mm_min: Mapped[float] = mapped_column(Float)
    gain_per_s: Mapped[float] = mapped_column(Float)
    tolerance_um: Mapped[float] = mapped_column(Float)
    tbe_um: Mapped[float] = mapped_column(Float)
    backlash_limit_um: Mapped[float | None] = mapped_column(Float, nullable=True)  # NULL: no limit
    state: Mapped[str] = mapped_column(String(10))
    tbe_uncertainty_um: Mapped[float | None] = mapped_column(Float, nullable=True)  # expanded, k = 2
    backlash_limit_uncertainty_um: Mapped[float | None] = mapped_column(Float, nullable=True)
    decision_rule: Mapped[str | None] = mapped_column(String(10), nullable=True)
    reason: Mapped[str | None] = mapped_column(Text, nullable=True)


class Alert(Base):
    """Raised when the axis' state reaches ALARM (a TBE above its tolerance); cleared
    by the first measurement back below; acknowledged by a person (key name)."""

    __tablename__ = "alerts"
    __table_args__ = (Index("ix_alerts_axis_cleared", "axis_id", "cleared_at"),)

    id: Mapped[int] = mapped_column(primary_key=True)
    axis_id: Mapped[int] = mapped_column(ForeignKey("axes.id", ondelete="CASCADE"))
    kind: Mapped[str] = mapped_column(String(30))
    raised_at: Mapped[datetime] = mapped_column(UtcDateTime)
    raised_by_result_id: Mapped[int | None] = mapped_column(ForeignKey("results.id", ondelete="SET NULL"), nullable=True)
    cleared_at: Mapped[datetime | None] = mapped_column(UtcDateTime, nullable=True)
    cleared_by_result_id: Mapped[int | None] = mapped_column(ForeignKey("results.id", ondelete="SET NULL"), nullable=True)
    acknowledged_at: Mapped[datetime | None] = mapped_column(UtcDateTime, nullable=True)
    acknowledged_by: Mapped[str | None] = mapped_column(String(100), nullable=True)
    task_name: Mapped[str | None] = mapped_column(String(100), nullable=True)
    tbe_um: Mapped[float | None] = mapped_column(Float, nullable=True)
    tolerance_um: Mapped[float | None] = mapped_column(Float, nullable=True)
    backlash_um: Mapped[float | None] = mapped_column(Float, nullable=True)
    backlash_limit_um: Mapped[float | None] = mapped_column(Float, nullable=True)
    message: Mapped[str] = mapped_column(Text)
    # the evidence when a circular test raised or cleared it (circular_tests.id; no foreign key, so
    # that the column is added in place, without rebuilding the table the work orders refer to)
    raised_by_circle_id: Mapped[int | None] = mapped_column(Integer, nullable=True)
    cleared_by_circle_id: Mapped[int | None] = mapped_column(Integer, nullable=True)


class CircularTestRow(Base):
    """A circular test (ISO 230-4) of two axes of a machine: the test itself (core.circle.io's
    JSON: samples, instrument), its figures, the agreement of each axis' reversal spikes with
    the TBE at its b̄ (Eq. 8), and each axis' decision against its circle tasks."""

    __tablename__ = "circular_tests"
    __table_args__ = (Index("ix_circular_tests_machine_measured", "machine_id", "measured_at"),)

    id: Mapped[int] = mapped_column(primary_key=True)
    machine_id: Mapped[int] = mapped_column(ForeignKey("machines.id", ondelete="CASCADE"))
    first_axis: Mapped[str] = mapped_column(String(20))  # the plane: the first axis is at 0°
    second_axis: Mapped[str] = mapped_column(String(20))
    first_axis_id: Mapped[int | None] = mapped_column(ForeignKey("axes.id", ondelete="SET NULL"), nullable=True,
                                                      index=True)
    second_axis_id: Mapped[int | None] = mapped_column(ForeignKey("axes.id", ondelete="SET NULL"), nullable=True,
                                                       index=True)
    radius_mm: Mapped[float] = mapped_column(Float)
    feed_mm_min: Mapped[float] = mapped_column(Float)
    directions: Mapped[str] = mapped_column(String(20))  # "ccw,cw"
    temperature_c: Mapped[float | None] = mapped_column(Float, nullable=True)
    utility_day: Mapped[float | None] = mapped_column(Float, nullable=True)
    measured_at: Mapped[datetime] = mapped_column(UtcDateTime)
    recorded_at: Mapped[datetime] = mapped_column(UtcDateTime)
    recorded_by: Mapped[str | None] = mapped_column(String(100), nullable=True)
    source: Mapped[str] = mapped_column(Text, default="")
    instrument: Mapped[str] = mapped_column(Text)  # JSON
    test: Mapped[str] = mapped_column(Text)  # JSON (core.circle.io): the passes' samples
    figures: Mapped[str | None] = mapped_column(Text, nullable=True)  # JSON: CircleFigures.to_dict()
    agreement: Mapped[str | None] = mapped_column(Text, nullable=True)  # JSON: axis -> Agreement.to_dict()
    decision: Mapped[str | None] = mapped_column(Text, nullable=True)  # JSON: axis -> CircleDecision.to_dict() | null
    state: Mapped[str | None] = mapped_column(String(10), nullable=True)  # the worst judged state, NULL: none judged


class TrendRollup(Base):
    """One hour of an axis' ok measurements, summarised (a trend whose cost does
    not grow with history): the count, the measurements with the smallest and the largest
    b̄ (their cycle ids: what a min/max downsampling to the screen keeps), and the moment sums of every
    trend criterion against temperature and utility day (core.history.MomentSums, packed),
    from which correlations and the thermal model of any range of whole hours follow.
    Rebuilt from its rows on every stored result of the hour."""

    __tablename__ = "trend_rollups"
    __table_args__ = (UniqueConstraint("axis_id", "bucket_start", name="uq_trend_rollups_axis_bucket"),)

    id: Mapped[int] = mapped_column(primary_key=True)
    axis_id: Mapped[int] = mapped_column(ForeignKey("axes.id", ondelete="CASCADE"))
    bucket_start: Mapped[datetime] = mapped_column(UtcDateTime)
    n: Mapped[int] = mapped_column(Integer)
    b_min_cycle_id: Mapped[int] = mapped_column(Integer)
    b_min_um: Mapped[float] = mapped_column(Float)
    b_max_cycle_id: Mapped[int] = mapped_column(Integer)
    b_max_um: Mapped[float] = mapped_column(Float)
    stats: Mapped[bytes] = mapped_column(LargeBinary)  # float64 [driver][criterion][field], little-endian


class ApiKey(Base):
    """An access key, stored as the SHA-256 of the secret (keys are 256-bit random)."""

    __tablename__ = "api_keys"

    id: Mapped[int] = mapped_column(primary_key=True)
    name: Mapped[str] = mapped_column(String(100), unique=True)
    role: Mapped[str] = mapped_column(String(10))
    key_prefix: Mapped[str] = mapped_column(String(20))
    key_sha256: Mapped[str] = mapped_column(String(64), unique=True)
    created_at: Mapped[datetime] = mapped_column(UtcDateTime)
    revoked_at: Mapped[datetime | None] = mapped_column(UtcDateTime, nullable=True)


# -- maintenance -------------------------------------------------------------------
ONE_ACTIVE_ORDER = "state IN ('open', 'acknowledged', 'repaired')"


class WorkOrder(Base):
    """A maintenance order on one axis (core.maintenance's state machine). At most one
    active (open, acknowledged or repaired) order per axis: a partial unique index, so two
    ALARMs stored at once, by two threads or two processes, still open one."""

    __tablename__ = "work_orders"
    __table_args__ = (
        Index("uq_work_orders_one_active", "axis_id", unique=True,
              sqlite_where=text(ONE_ACTIVE_ORDER), postgresql_where=text(ONE_ACTIVE_ORDER)),
        Index("ix_work_orders_axis_opened", "axis_id", "opened_at"),
    )

    id: Mapped[int] = mapped_column(primary_key=True)
    axis_id: Mapped[int] = mapped_column(ForeignKey("axes.id", ondelete="CASCADE"))
    kind: Mapped[str] = mapped_column(String(20))  # corrective | condition_based (EN 13306)
    state: Mapped[str] = mapped_column(String(20))
    opened_at: Mapped[datetime] = mapped_column(UtcDateTime)
    opened_by_result_id: Mapped[int | None] = mapped_column(ForeignKey("results.id", ondelete="SET NULL"), nullable=True)
    alert_id: Mapped[int | None] = mapped_column(ForeignKey("alerts.id", ondelete="SET NULL"), nullable=True)
    binding_task: Mapped[str | None] = mapped_column(String(100), nullable=True)
    tolerance_um: Mapped[float | None] = mapped_column(Float, nullable=True)
    backlash_um: Mapped[float | None] = mapped_column(Float, nullable=True)
    backlash_uncertainty_um: Mapped[float | None] = mapped_column(Float, nullable=True)
    tbe_um: Mapped[float | None] = mapped_column(Float, nullable=True)
    tbe_uncertainty_um: Mapped[float | None] = mapped_column(Float, nullable=True)
    backlash_limit_um: Mapped[float | None] = mapped_column(Float, nullable=True)
    restore_below_um: Mapped[float | None] = mapped_column(Float, nullable=True)
    due_at: Mapped[datetime | None] = mapped_column(UtcDateTime, nullable=True)  # the prognosis' date, if any
    recommendation: Mapped[str] = mapped_column(Text)
    verification_cycle_id: Mapped[int | None] = mapped_column(ForeignKey("cycles.id", ondelete="SET NULL"),
                                                              nullable=True)
    verification: Mapped[str | None] = mapped_column(Text, nullable=True)  # JSON: the last core.maintenance.Verification
    # the circular test whose decision opened it (circular_tests.id; no foreign key, as Alert's)
    opened_by_circle_id: Mapped[int | None] = mapped_column(Integer, nullable=True)
    closed_at: Mapped[datetime | None] = mapped_column(UtcDateTime, nullable=True)

    transitions: Mapped[list[WorkOrderTransition]] = relationship(
        order_by="WorkOrderTransition.id", cascade="all, delete-orphan")


class WorkOrderTransition(Base):
    """Every step of an order: when, by which key (or ``mebm`` for the service), why."""

    __tablename__ = "work_order_transitions"

    id: Mapped[int] = mapped_column(primary_key=True)
    order_id: Mapped[int] = mapped_column(ForeignKey("work_orders.id", ondelete="CASCADE"), index=True)
    at: Mapped[datetime] = mapped_column(UtcDateTime)
    from_state: Mapped[str | None] = mapped_column(String(20), nullable=True)
    to_state: Mapped[str] = mapped_column(String(20))
    by: Mapped[str] = mapped_column(String(100))
    note: Mapped[str] = mapped_column(Text, default="")
    figures: Mapped[str | None] = mapped_column(Text, nullable=True)  # JSON (a failed verification's figures)


class Repair(Base):
    """What was done to an axis, by whom and when; optionally on an order, and for a
    ``compensation_loaded`` repair the measurement whose table was loaded."""

    __tablename__ = "repairs"
    __table_args__ = (Index("ix_repairs_axis_performed", "axis_id", "performed_at"),)

    id: Mapped[int] = mapped_column(primary_key=True)
    axis_id: Mapped[int] = mapped_column(ForeignKey("axes.id", ondelete="CASCADE"))
    order_id: Mapped[int | None] = mapped_column(ForeignKey("work_orders.id", ondelete="SET NULL"), nullable=True)
    kind: Mapped[str] = mapped_column(String(30))
    note: Mapped[str] = mapped_column(Text, default="")
    performed_at: Mapped[datetime] = mapped_column(UtcDateTime)
    recorded_at: Mapped[datetime] = mapped_column(UtcDateTime)
    recorded_by: Mapped[str] = mapped_column(String(100))
    compensation_cycle_id: Mapped[int | None] = mapped_column(ForeignKey("cycles.id", ondelete="SET NULL"),
                                                              nullable=True)
    compensation_file: Mapped[str | None] = mapped_column(String(300), nullable=True)
    before_result_id: Mapped[int | None] = mapped_column(ForeignKey("results.id", ondelete="SET NULL"), nullable=True)


class UiSession(Base):
    """A dashboard session or a one-time sign-in link (``kind``), stored as the SHA-256
    of its random token: sessions survive a restart and are shared by every ``serve``
    process on the database. Ended when its key is revoked (``revoked_at``)."""

    __tablename__ = "ui_sessions"

    id: Mapped[int] = mapped_column(primary_key=True)
    kind: Mapped[str] = mapped_column(String(10))  # "session" or "link"
    token_sha256: Mapped[str] = mapped_column(String(64), unique=True)
    key_id: Mapped[int] = mapped_column(ForeignKey("api_keys.id", ondelete="CASCADE"), index=True)
    created_at: Mapped[datetime] = mapped_column(UtcDateTime)
    last_seen_at: Mapped[datetime] = mapped_column(UtcDateTime)
    expires_at: Mapped[datetime] = mapped_column(UtcDateTime, index=True)
    revoked_at: Mapped[datetime | None] = mapped_column(UtcDateTime, nullable=True)


class Worker(Base):
    """A ``mebm serve`` process that runs cycles: one row per process start.
    Live while ``heartbeat_at`` is younger than its lease time."""

    __tablename__ = "workers"

    id: Mapped[str] = mapped_column(String(36), primary_key=True)  # a uuid per process start
    name: Mapped[str] = mapped_column(String(100), index=True)
    host: Mapped[str] = mapped_column(String(200))
    pid: Mapped[int] = mapped_column(Integer)
    axes: Mapped[str | None] = mapped_column(Text, nullable=True)  # JSON list of machine/axis patterns; NULL: any
    lease_s: Mapped[float] = mapped_column(Float)
    started_at: Mapped[datetime] = mapped_column(UtcDateTime)
    heartbeat_at: Mapped[datetime] = mapped_column(UtcDateTime)
    stopped_at: Mapped[datetime | None] = mapped_column(UtcDateTime, nullable=True)
    takeovers: Mapped[int] = mapped_column(Integer, default=0, server_default="0")


class AxisLease(Base):
    """Who runs an axis' cycles: one row per axis, owned by one worker until ``expires_at``
    (database time), renewed by the owner's heartbeat. ``owner`` NULL: free."""

    __tablename__ = "axis_leases"

    axis_id: Mapped[int] = mapped_column(ForeignKey("axes.id", ondelete="CASCADE"), primary_key=True)
    owner: Mapped[str | None] = mapped_column(String(36), nullable=True, index=True)
    previous_owner: Mapped[str | None] = mapped_column(String(36), nullable=True)
    acquired_at: Mapped[datetime | None] = mapped_column(UtcDateTime, nullable=True)
    expires_at: Mapped[datetime] = mapped_column(UtcDateTime)


class WebhookMessage(Base):
    """One webhook message to one receiver URL, kept until it is delivered (durable
    webhooks): a message survives a restart, a receiver outage longer than
    the retries, and a worker that died while sending it (another live worker takes it
    once ``claimed_until`` has passed). ``state``: ``pending`` (to send at ``next_at``),
    ``delivered`` or ``failed`` (every attempt used; kept for an admin to re-queue)."""

    __tablename__ = "webhook_messages"
    __table_args__ = (Index("ix_webhook_messages_state_next_at", "state", "next_at"),)

    id: Mapped[int] = mapped_column(Integer, primary_key=True)
    msg_id: Mapped[str] = mapped_column(String(40), index=True)  # the webhook-id header, the same on every retry
    url: Mapped[str] = mapped_column(Text)
    event_type: Mapped[str] = mapped_column(String(60))
    axis_id: Mapped[int] = mapped_column(Integer)
    body: Mapped[str] = mapped_column(Text)
    created_at: Mapped[datetime] = mapped_column(UtcDateTime)
    state: Mapped[str] = mapped_column(String(10))
    attempts: Mapped[int] = mapped_column(Integer, default=0, server_default="0")
    next_at: Mapped[datetime] = mapped_column(UtcDateTime)
    last_status: Mapped[int | None] = mapped_column(Integer, nullable=True)  # HTTP status of the last attempt
    last_error: Mapped[str | None] = mapped_column(Text, nullable=True)
    done_at: Mapped[datetime | None] = mapped_column(UtcDateTime, nullable=True)
    claimed_by: Mapped[str | None] = mapped_column(String(36), nullable=True)
    claimed_until: Mapped[datetime | None] = mapped_column(UtcDateTime, nullable=True)
