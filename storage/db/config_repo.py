"""Repository: machines, axes, machining tasks, schedules and access keys."""

from __future__ import annotations

import hashlib
import math
import secrets
import uuid
from collections.abc import Sequence
from datetime import datetime

from sqlalchemy import select
from sqlalchemy.orm import Session, selectinload

from core.dataset import AxisSpec
from core.criteria.uncertainty import Instruments
from core.errors import InputError
from core.tbe import DECISION_RULES, MachiningTask
from storage.db import leases, ui_sessions_repo
from storage.db.errors import ConflictError, NotFoundError
from storage.db.models import ApiKey, Axis, Machine, MachiningTaskRow
from storage.db.names import collision, collision_message
from storage.db.records import ROLES, AxisRecord, AxisSettings, KeyRecord, MachineRecord, Schedule, as_utc, utcnow

KEY_PREFIX = "mebm_"
NAMES_LOCK = 0x6D65626D0003  # advisory lock key (PostgreSQL): the interface-name check of a new machine or axis


# -- machines ------------------------------------------------------------------------------
def _machine(m: Machine) -> MachineRecord:
    return MachineRecord(id=m.id, name=m.name, description=m.description, axis_ids=tuple(a.id for a in m.axes),
                         uuid=m.uuid or "")


def create_machine(s: Session, name: str, description: str = "") -> MachineRecord:
    name = name.strip()
    if not name:
        raise InputError("machine name must not be empty")
    leases.serialize(s, NAMES_LOCK)  # two admins adding "m a" and "m_a" at once: one after the other
    if s.scalar(select(Machine.id).where(Machine.name == name)) is not None:
        raise ConflictError(f"a machine named {name!r} exists already")
    other = collision(name, s.scalars(select(Machine.name)))
    if other is not None:
        raise ConflictError(collision_message("machine", name, other))
    m = Machine(name=name, uuid=str(uuid.uuid4()), description=description, created_at=utcnow())
    s.add(m)
    s.flush()
    return MachineRecord(id=m.id, name=m.name, description=m.description, axis_ids=(), uuid=m.uuid)


def list_machines(s: Session) -> list[MachineRecord]:
    rows = s.scalars(select(Machine).options(selectinload(Machine.axes)).order_by(Machine.id))
    return [_machine(m) for m in rows]


def find_machine(s: Session, name: str) -> MachineRecord | None:
    m = s.scalar(select(Machine).where(Machine.name == name).options(selectinload(Machine.axes)))
    return None if m is None else _machine(m)


# -- axes ------------------------------------------------------------------------------------
def _task(row: MachiningTaskRow, gain_per_s: float) -> MachiningTask:
    return MachiningTask(
        name=row.name, profile=row.profile, feed_mm_min=row.feed_mm_min, gain_per_s=gain_per_s,
        tolerance_um=row.tolerance_um, radius_mm=row.radius_mm, angle_deg=row.angle_deg,
    )


def _axis(a: Axis) -> AxisRecord:
    spec = AxisSpec(
        name=a.name, transmission_mm_per_rev=a.transmission_mm_per_rev, screw_lead_mm=a.screw_lead_mm,
        position_gain_per_s=a.position_gain_per_s, travel_mm=(a.travel_start_mm, a.travel_end_mm),
    )
    settings = AxisSettings(
        spec=spec, controller_url=a.controller_url, measure_feed_mm_min=a.measure_feed_mm_min,
        measure_acceleration_mm_s2=a.measure_acceleration_mm_s2, warning_fraction=a.warning_fraction,
        decision_rule=a.decision_rule or "guarded",
        **({} if a.worst_case_temperature_c is None else {"worst_case_temperature_c": a.worst_case_temperature_c}),
        schedule=Schedule(a.schedule_interval_s, a.schedule_cron, a.schedule_enabled),
        tasks=tuple(_task(t, a.position_gain_per_s) for t in a.tasks),
        in_service_since=as_utc(a.in_service_since), instruments=_instruments(a),
    )
    return AxisRecord(id=a.id, machine_id=a.machine_id, machine_name=a.machine.name, settings=settings,
                      uuid=a.uuid or "", machine_uuid=a.machine.uuid or "")


INSTRUMENT_COLUMNS = ("scale_accuracy_um", "scale_accuracy_um_per_m", "thermometer_class", "thermal_expansion_per_k")


def _instruments(a: Axis) -> Instruments:
    """The axis' instruments; a column left empty (an axis stored before they were) is the default."""
    return Instruments(**{k: getattr(a, k) for k in INSTRUMENT_COLUMNS if getattr(a, k) is not None})


def _check_settings(st: AxisSettings) -> None:
    if not (math.isfinite(st.measure_feed_mm_min) and st.measure_feed_mm_min > 0):
        raise InputError(f"measure_feed_mm_min (={st.measure_feed_mm_min}) must be > 0")
    if not (math.isfinite(st.measure_acceleration_mm_s2) and st.measure_acceleration_mm_s2 > 0):
        raise InputError(f"measure_acceleration_mm_s2 (={st.measure_acceleration_mm_s2}) must be > 0")
    if not 0.0 < st.warning_fraction <= 1.0:
        raise InputError(f"warning_fraction (={st.warning_fraction}) must be in (0, 1]")
    if st.decision_rule not in DECISION_RULES:
        raise InputError(f"decision_rule (={st.decision_rule!r}) must be one of {DECISION_RULES}")
    if not (math.isfinite(st.worst_case_temperature_c) and -50.0 <= st.worst_case_temperature_c <= 100.0):
        raise InputError(f"worst_case_temperature_c (={st.worst_case_temperature_c}) must be within -50..100 °C")
    if not st.controller_url:
        raise InputError("controller_url must not be empty")


def create_axis(s: Session, machine_id: int, st: AxisSettings) -> AxisRecord:
    m = s.get(Machine, machine_id)
    if m is None:
        raise NotFoundError("machine", machine_id)
    _check_settings(st)
    leases.serialize(s, NAMES_LOCK)
    if s.scalar(select(Axis.id).where(Axis.machine_id == machine_id, Axis.name == st.spec.name)) is not None:
        raise ConflictError(f"machine {m.name!r} has an axis {st.spec.name!r} already")
    other = collision(st.spec.name, s.scalars(select(Axis.name).where(Axis.machine_id == machine_id)))
    if other is not None:
        raise ConflictError(f"machine {m.name!r}: " + collision_message("axis", st.spec.name, other))
    now = utcnow()
    a = Axis(
        machine_id=machine_id, name=st.spec.name, uuid=str(uuid.uuid4()),
        transmission_mm_per_rev=st.spec.transmission_mm_per_rev, screw_lead_mm=st.spec.screw_lead_mm,
        position_gain_per_s=st.spec.position_gain_per_s,
        travel_start_mm=st.spec.travel_mm[0], travel_end_mm=st.spec.travel_mm[1],
        controller_url=st.controller_url, measure_feed_mm_min=st.measure_feed_mm_min,
        measure_acceleration_mm_s2=st.measure_acceleration_mm_s2, warning_fraction=st.warning_fraction,
        decision_rule=st.decision_rule, worst_case_temperature_c=st.worst_case_temperature_c,
        schedule_interval_s=st.schedule.interval_s, schedule_cron=st.schedule.cron,
        schedule_enabled=st.schedule.enabled, in_service_since=st.in_service_since or now, created_at=now,
        **{k: getattr(st.instruments, k) for k in INSTRUMENT_COLUMNS},
    )
    s.add(a)
    s.flush()
    _replace_tasks(s, a, st.tasks)
    s.flush()
    return get_axis(s, a.id)


def _load_axis(s: Session, axis_id: int) -> Axis:
    a = s.get(Axis, axis_id, options=[selectinload(Axis.tasks), selectinload(Axis.machine)])
    if a is None:
        raise NotFoundError("axis", axis_id)
    return a


def get_axis(s: Session, axis_id: int) -> AxisRecord:
    return _axis(_load_axis(s, axis_id))


def list_axes(s: Session, machine_id: int | None = None) -> list[AxisRecord]:
    q = select(Axis).options(selectinload(Axis.tasks), selectinload(Axis.machine)).order_by(Axis.id)
    if machine_id is not None:
        if s.get(Machine, machine_id) is None:
            raise NotFoundError("machine", machine_id)
        q = q.where(Axis.machine_id == machine_id)
    return [_axis(a) for a in s.scalars(q)]


def find_axis(s: Session, machine_name: str, axis_name: str) -> AxisRecord | None:
    a = s.scalar(select(Axis).join(Machine).where(Machine.name == machine_name, Axis.name == axis_name))
    return None if a is None else get_axis(s, a.id)


def set_schedule(s: Session, axis_id: int, schedule: Schedule) -> AxisRecord:
    a = _load_axis(s, axis_id)
    a.schedule_interval_s, a.schedule_cron, a.schedule_enabled = schedule.interval_s, schedule.cron, schedule.enabled
    s.flush()
    return _axis(a)


def _replace_tasks(s: Session, a: Axis, tasks: Sequence[MachiningTask]) -> None:
    names = [t.name for t in tasks]
    if len(set(names)) != len(names):
        raise InputError(f"task names must be unique, got {names}")
    a.tasks.clear()
    s.flush()
    for t in tasks:
        a.tasks.append(MachiningTaskRow(
            name=t.name, profile=t.profile, radius_mm=t.radius_mm if t.profile == "circle" else None,
            angle_deg=t.angle_deg if t.profile == "line" else None, feed_mm_min=t.feed_mm_min,
            tolerance_um=t.tolerance_um,
        ))


def set_tasks(s: Session, axis_id: int, tasks: Sequence[MachiningTask]) -> AxisRecord:
    """Replace the axis' machining tasks (their gain is the axis' K)."""
    a = _load_axis(s, axis_id)
    _replace_tasks(s, a, tasks)
    s.flush()
    s.expire(a)
    return get_axis(s, axis_id)


# -- access keys ---------------------------------------------------------------------------
def hash_key(secret: str) -> str:
    return hashlib.sha256(secret.encode("utf-8")).hexdigest()


def _key(k: ApiKey) -> KeyRecord:
    return KeyRecord(id=k.id, name=k.name, role=k.role, key_prefix=k.key_prefix,
                     created_at=as_utc(k.created_at), revoked_at=as_utc(k.revoked_at))


def create_key(s: Session, name: str, role: str, *, secret: str | None = None) -> tuple[KeyRecord, str]:
    """A new key; returns the record and the secret (shown once, stored only hashed)."""
    if role not in ROLES:
        raise InputError(f"role (={role!r}) must be one of {ROLES}")
    name = name.strip()
    if not name:
        raise InputError("key name must not be empty")
    if s.scalar(select(ApiKey.id).where(ApiKey.name == name)) is not None:
        raise ConflictError(f"a key named {name!r} exists already")
    if secret is None:
        secret = KEY_PREFIX + secrets.token_urlsafe(32)
    elif len(secret) < 16:
        raise InputError("a key must be at least 16 characters long")
    digest = hash_key(secret)
    if s.scalar(select(ApiKey.id).where(ApiKey.key_sha256 == digest)) is not None:
        raise ConflictError("this key is registered already")
    k = ApiKey(name=name, role=role, key_prefix=secret[:9], key_sha256=digest, created_at=utcnow())
    s.add(k)
    s.flush()
    return _key(k), secret


def authenticate(s: Session, secret: str) -> KeyRecord | None:
    """The live key with this secret, or None."""
    k = s.scalar(select(ApiKey).where(ApiKey.key_sha256 == hash_key(secret)))
    if k is None or k.revoked_at is not None:
        return None
    return _key(k)


def find_key_by_secret(s: Session, secret: str) -> KeyRecord | None:
    """The key with this secret, revoked or not (start-up: a revoked bootstrap key stays revoked)."""
    k = s.scalar(select(ApiKey).where(ApiKey.key_sha256 == hash_key(secret)))
    return None if k is None else _key(k)


def list_keys(s: Session) -> list[KeyRecord]:
    return [_key(k) for k in s.scalars(select(ApiKey).order_by(ApiKey.id))]


def revoke_key(s: Session, key_id: int, when: datetime | None = None) -> KeyRecord:
    k = s.get(ApiKey, key_id)
    if k is None:
        raise NotFoundError("key", key_id)
    if k.revoked_at is None:
        k.revoked_at = when or utcnow()
    s.flush()
    ui_sessions_repo.revoke_for_key(s, key_id, k.revoked_at)  # its dashboard sessions end with it
    return _key(k)


def find_key(s: Session, name: str) -> KeyRecord | None:
    k = s.scalar(select(ApiKey).where(ApiKey.name == name))
    return None if k is None else _key(k)
