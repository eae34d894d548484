"""Every number of the configuration has its bounds, every name its alphabet: a value
outside them is refused when the configuration is loaded, with one line naming the key,
the value and the allowed range (:class:`ConfigError`), never at use (a retry period of
-1 s spins a thread; a timeout beyond what a timer holds fails every request).

:data:`BOUNDS` is the single table of the service-wide numbers (docs/operations.md lists
it); an axis' and its tasks' numbers and names are bounded as the REST API bounds them
(:class:`api.service.config.input.AxisIn`, :class:`~api.service.config.input.TaskIn`,
:class:`~api.service.config.input.ScheduleIn`, :class:`~api.service.config.input.MachineIn`),
so a file and a request accept the same axis.
"""

from __future__ import annotations

import math
import re
from collections.abc import Iterable
from dataclasses import dataclass

import annotated_types
from pydantic import BaseModel

from api.service.config.input import MAX_TRAVEL_MM, AxisIn, MachineIn, ScheduleIn, TaskIn
from api.service.config.settings import AxisConfig, ConfigError, Settings


@dataclass(frozen=True)
class Bound:
    """``key`` (the file's name of the option) lies within ``low..high`` (both included)."""

    key: str
    low: float
    high: float
    unit: str = ""
    why: str = ""
    open_ends: bool = False  # the ends themselves are outside

    def check(self, value: float) -> None:
        inside = (self.low < value < self.high) if self.open_ends else (self.low <= value <= self.high)
        if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value) or not inside:
            unit = f" {self.unit}" if self.unit else ""
            why = f" ({self.why})" if self.why else ""
            ends = ", ends excluded" if self.open_ends else ""
            raise ConfigError(f"{self.key} (={value!r}) must be {self.range}{unit}{ends}{why}")

    @property
    def range(self) -> str:
        """``low..high`` as written in the docs (whole numbers in full)."""
        return f"{number(self.low)}..{number(self.high)}"


def number(x: float) -> str:
    """``x`` written out: a whole number in full (16777216, not 1.67772e+07), else ``%g``."""
    return str(int(x)) if float(x).is_integer() and abs(x) < 1e15 else f"{x:g}"


DAY_S = 86400.0
WEEK_S = 7 * DAY_S

# (the file's key, its attribute path in Settings); None: not set
BOUNDS: tuple[tuple[Bound, str], ...] = (
    (Bound("server.port", 0, 65535, why="0: a free port"), "port"),
    (Bound("server.status_max_age_s", 0.1, DAY_S, "s"), "status_max_age_s"),
    (Bound("storage.min_free_disk_mb", 0, 1e7, "MB"), "min_free_disk_mb"),
    (Bound("storage.spool_reserve_mb", 0, 10240, "MB", "0: none"), "spool_reserve_mb"),
    (Bound("storage.spool_slots", 0, 64, why="0: none"), "spool_slots"),
    (Bound("storage.spool_slot_mb", 0.01, 64, "MB"), "spool_slot_mb"),
    (Bound("scheduler.spool_retry_s", 0.1, DAY_S, "s"), "spool_retry_s"),
    (Bound("scheduler.cycle_processes", 0, 64, why="0: cycles run in the service's own process"), "cycle_processes"),
    (Bound("retention.keep_last_runs", 0, 10_000_000, "runs"), "retention.keep_last_runs"),
    (Bound("retention.keep_around_events", 0, 10_000, "runs"), "retention.keep_around_events"),
    (Bound("retention.max_runs", 0, 10_000_000, "runs"), "retention.max_runs"),
    (Bound("retention.interval_s", 1, 365 * DAY_S, "s"), "retention_interval_s"),
    (Bound("simulator.time_scale", 0.01, 1000), "simulator.time_scale"),
    (Bound("simulator.servo_rate_hz", 1, 100_000, "Hz"), "simulator.servo_rate_hz"),
    (Bound("simulator.backlash_um_at_20c", 0, 10_000, "µm"), "simulator.backlash_um_at_20c"),
    (Bound("simulator.backlash_um_per_k", -1000, 1000, "µm/K"), "simulator.backlash_um_per_k"),
    (Bound("simulator.temperature_mean_c", -50, 100, "°C"), "simulator.temperature_mean_c"),
    (Bound("simulator.temperature_amplitude_c", 0, 100, "°C"), "simulator.temperature_amplitude_c"),
    (Bound("simulator.temperature_period_s", 1, 1e8, "s"), "simulator.temperature_period_s"),
    (Bound("simulator.cyclic_error_um", 0, 1000, "µm"), "simulator.cyclic_error_um"),
    (Bound("simulator.wear_um_per_day", 0, 10_000, "µm/day"), "simulator.wear_um_per_day"),
    (Bound("simulator.utility_days_per_s", 1e-9, 1e6, "days/s"), "simulator.utility_days_per_s"),
    (Bound("limits.max_body_bytes", 1024, 1_000_000_000, "bytes"), "limits.max_body_bytes"),
    (Bound("limits.max_circle_body_bytes", 1024, 1_000_000_000, "bytes"), "limits.max_circle_body_bytes"),
    (Bound("limits.max_header_bytes", 1024, 16 * 1024 * 1024, "bytes"), "limits.max_header_bytes"),
    (Bound("limits.max_headers", 8, 10_000), "limits.max_headers"),
    (Bound("limits.header_timeout_s", 0.1, 300, "s"), "limits.header_timeout_s"),
    (Bound("limits.triggers_per_minute", 0.001, 1e6), "limits.triggers_per_minute"),
    (Bound("limits.trigger_burst", 1, 1_000_000), "limits.trigger_burst"),
    (Bound("limits.auth_failures_per_minute", 0.001, 1e6), "limits.auth_failures_per_minute"),
    (Bound("limits.auth_failure_burst", 1, 1_000_000), "limits.auth_failure_burst"),
    (Bound("limits.auth_address_failures_per_minute", 0.001, 1e6), "limits.auth_address_failures_per_minute"),
    (Bound("limits.auth_address_failure_burst", 1, 1_000_000), "limits.auth_address_failure_burst"),
    (Bound("limits.gap_diagnoses_pending", 1, 64), "limits.gap_diagnoses_pending"),
    (Bound("limits.gap_diagnosis_timeout_s", 1, WEEK_S, "s"), "limits.gap_diagnosis_timeout_s"),
    (Bound("limits.gap_diagnosis_nice", 0, 19, why="0: the service's own priority"), "limits.gap_diagnosis_nice"),
    (Bound("limits.plot_renders", 1, 16, why="figures drawn at once"), "limits.plot_renders"),
    (Bound("limits.plot_queue", 0, 1000, why="figures waiting to be drawn"), "limits.plot_queue"),
    (Bound("limits.plot_window_step_s", 1, DAY_S, "s"), "limits.plot_window_step_s"),
    (Bound("mqtt.outbox_max", 1, 1_000_000, "messages"), "mqtt.outbox_max"),
    (Bound("webhooks.timeout_s", 0.1, 300, "s"), "webhooks.timeout_s"),
    (Bound("webhooks.max_attempts", 1, 100), "webhooks.max_attempts"),
    (Bound("webhooks.log_max", 1, 100_000, "attempts"), "webhooks.log_max"),
    (Bound("webhooks.keep_delivered_days", 0.001, 3650, "days"), "webhooks.keep_delivered_days"),
    (Bound("webhooks.max_failed", 1, 10_000_000, "messages"), "webhooks.max_failed"),
    (Bound("mtconnect.buffer_size", 1, 10_000_000, "observations"), "mtconnect.buffer_size"),
    (Bound("mtconnect.shdr_port", 0, 65535, why="0: a free port"), "mtconnect.shdr_port"),
    (Bound("maintenance.horizon_days", 0, 3650, "days"), "maintenance.horizon_days"),
    (Bound("maintenance.fixed_interval_days", 0.001, 36500, "days"), "maintenance.fixed_interval_days"),
    (Bound("worker.lease_s", 1, DAY_S, "s"), "worker.lease_s"),
    (Bound("worker.tick_s", 0.01, DAY_S / 3, "s", "and at most lease_s / 3"), "worker.tick_s"),
)


def _value(settings: Settings, path: str):
    v = settings
    for part in path.split("."):
        v = getattr(v, part)
    return v


def check_bounds(settings: Settings, keys: Iterable[str] | None = None) -> Settings:
    """``settings`` if every number named by ``keys`` (the file's keys; None: every one) is
    within its bounds, and every machine's name in its alphabet; else :class:`ConfigError`."""
    wanted = None if keys is None else set(keys)
    for bound, path in BOUNDS:
        if wanted is not None and bound.key not in wanted:
            continue
        value = _value(settings, path)
        if value is not None:
            bound.check(value)
    if wanted is None or "machines" in wanted:
        for i, (name, _) in enumerate(settings.machines):
            check_name(MachineIn, "name", name, f"machines[{i}].name")
    return settings


def keys_of(doc) -> set[str]:
    """The ``table.key`` names of a parsed configuration file (one level deep), and
    ``machines`` when it has machines."""
    keys = {f"{t}.{k}" for t, table in doc.items() if isinstance(table, dict) for k in table}
    return keys | ({"machines"} if "machines" in doc else set())


def _constraints(model: type[BaseModel], field: str) -> tuple[float, float, bool, str | None, int | None]:
    """(low, high, open ends, pattern, max_length) of ``model.field`` as pydantic checks it."""
    low, high, open_ends, pattern, max_length = -math.inf, math.inf, False, None, None
    for m in model.model_fields[field].metadata:
        if isinstance(m, annotated_types.Ge):
            low = float(m.ge)
        elif isinstance(m, annotated_types.Gt):
            low, open_ends = float(m.gt), True
        elif isinstance(m, annotated_types.Le):
            high = float(m.le)
        elif isinstance(m, annotated_types.Lt):
            high, open_ends = float(m.lt), True
        elif isinstance(m, annotated_types.MaxLen):
            max_length = m.max_length
        elif getattr(m, "pattern", None) is not None:
            pattern = m.pattern
    return low, high, open_ends, pattern, max_length


# what each name's pattern allows, in words
ALPHABETS = {
    (AxisIn, "name"): "lower-case letters a-z, digits and _, starting with a letter",
    (MachineIn, "name"): "letters A-Z a-z, digits, space, '.', '_' and '-', starting with a letter or digit",
    (TaskIn, "name"): "any characters, not only blanks",
}


def check_name(model: type[BaseModel], field: str, value: str, key: str) -> None:
    """``value`` in the alphabet and length the REST API allows for ``model.field``."""
    *_, pattern, max_length = _constraints(model, field)
    shown = value if len(value) <= 120 else value[:120] + "…"
    if (max_length is not None and len(value) > max_length) or (pattern is not None and not re.search(pattern, value)):
        alphabet = ALPHABETS.get((model, field), f"matching {pattern}")
        raise ConfigError(f"{key} (={shown!r}) must be {alphabet}, at most {max_length} characters")


def check_number(model: type[BaseModel], field: str, value: float | None, key: str, unit: str = "") -> None:
    """``value`` within the bounds the REST API allows for ``model.field`` (None: not set)."""
    if value is None:
        return
    low, high, open_ends, _, _ = _constraints(model, field)
    Bound(key, low, high, unit, open_ends=open_ends).check(value)


def check_axis_name(name: str, where: str) -> None:
    """An axis' name (``where.name``) in the alphabet of the REST API's axis body, checked
    before the name is used anywhere (a folder, a topic, a node)."""
    check_name(AxisIn, "name", name, f"{where}.name")


def check_axis(axis: AxisConfig, where: str) -> AxisConfig:
    """An axis of the configuration file within the bounds of the REST API's axis body."""
    st, spec = axis.settings, axis.settings.spec
    check_name(AxisIn, "name", spec.name, f"{where}.name")
    for field, value, unit in (("transmission_mm_per_rev", spec.transmission_mm_per_rev, "mm/rev"),
                               ("screw_lead_mm", spec.screw_lead_mm, "mm"),
                               ("position_gain_per_s", spec.position_gain_per_s, "1/s"),
                               ("measure_feed_mm_min", st.measure_feed_mm_min, "mm/min"),
                               ("measure_acceleration_mm_s2", st.measure_acceleration_mm_s2, "mm/s²"),
                               ("warning_fraction", st.warning_fraction, "")):
        check_number(AxisIn, field, value, f"{where}.{field}", unit)
    for end, x in zip(("start", "end"), spec.travel_mm):
        Bound(f"{where}.travel_mm {end}", -MAX_TRAVEL_MM, MAX_TRAVEL_MM, "mm").check(x)
    check_number(ScheduleIn, "interval_s", st.schedule.interval_s, f"{where}.schedule_interval_s", "s")
    for i, t in enumerate(st.tasks):
        check_name(TaskIn, "name", t.name, f"{where}.tasks[{i}].name")
        for field, value, unit in (("feed_mm_min", t.feed_mm_min, "mm/min"), ("tolerance_um", t.tolerance_um, "µm"),
                                   ("radius_mm", t.radius_mm, "mm"), ("angle_deg", t.angle_deg, "°")):
            check_number(TaskIn, field, value, f"{where}.tasks[{i}].{field}", unit)
    return axis
