"""Running one measurement cycle on an axis: the runner the scheduler calls.

A runner takes the stored axis and the controller URL and returns a
:class:`CycleOutcome`; it never raises for a failed measurement (the failure is an
outcome with its reason). The production runner is the acquisition layer's cycle
(``acquisition.cycle.run_cycle``: a round trip with over-travel, trace validation,
criteria); tests inject their own.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Protocol

import numpy as np

from acquisition import cycle as acq_cycle
from acquisition.driver import ControllerDriver
from acquisition.url import driver_from_url
from core.criteria import RoundTripResult, analyze_round_trip
from core.criteria.uncertainty import UncertaintyInputs
from core.errors import MebmError
from storage.db import AxisRecord


@dataclass(frozen=True)
class CycleOutcome:
    """What one cycle produced. ``ok``: the raw trace and its analysis are present.

    Arrays are the raw round trip (time_s, motor_rev, table_mm), kept on disk as the
    dataset run; ``uncertainty_um`` is the backlash uncertainty the acquisition states
    (sampling skew times speed for unlatched modes, 0 when latched)."""

    ok: bool
    reason: str | None = None
    time_s: np.ndarray | None = None
    motor_rev: np.ndarray | None = None
    table_mm: np.ndarray | None = None
    command_mm: np.ndarray | None = None
    temperature_c: float | None = None
    uncertainty_um: float | None = None
    round_trip: RoundTripResult | None = None
    feed_mm_min: float | None = None
    acceleration_mm_s2: float | None = None
    trigger: str | None = None  # "active" (mebm started the round trip) or "passive" (the CNC did)

    @staticmethod
    def failed(reason: str, temperature_c: float | None = None) -> "CycleOutcome":
        return CycleOutcome(ok=False, reason=reason, temperature_c=temperature_c)


class CycleRunner(Protocol):
    def __call__(self, axis: AxisRecord, controller_url: str) -> CycleOutcome: ...


def useful_travel_mm(axis: AxisRecord) -> tuple[float, float]:
    """For a trace programmed over the travel only (no over-travel): the travel minus
    the reversal zones (max(5 mm, 1 %) at each end) where the table still settles."""
    a, b = axis.spec.travel_mm
    inset = max(5.0, 0.01 * (b - a))
    if b - a <= 4 * inset:
        inset = (b - a) / 8
    return a + inset, b - inset


def analyse(axis: AxisRecord, time_s, motor_rev, table_mm, *, sampling_bound_um: float = 0.0) -> RoundTripResult:
    """Backlash profile and lead criteria of a raw round trip (core, Section 3).

    A trace programmed with over-travel (``acquisition.cycle.default_program``) is
    analysed over the whole travel, like the live cycle, so a spooled run re-analysed
    after a database outage gives the same result; a shorter one over the inset
    :func:`useful_travel_mm`."""
    x = np.asarray(table_mm, dtype=float)
    lo, hi = axis.spec.travel_mm
    travel = (lo, hi) if x.size and x.min() < lo - 0.5 and x.max() > hi + 0.5 else useful_travel_mm(axis)
    return analyze_round_trip(time_s, motor_rev, table_mm, axis.spec, useful_travel_mm=travel,
                              uncertainty=UncertaintyInputs(sampling_bound_um=sampling_bound_um))


class DriverRunner:
    """The production runner: the acquisition cycle through the driver for the URL
    (``modbus://…``, ``canopen://…``; ``acquisition.url``)."""

    def __init__(self, driver_factory: Callable[[str], ControllerDriver] | None = None, *, timeout_s: float = 2.0):
        self.driver_factory = driver_factory or (lambda url: driver_from_url(url, timeout_s=timeout_s))

    def __call__(self, axis: AxisRecord, controller_url: str) -> CycleOutcome:
        st = axis.settings
        try:
            driver = self.driver_factory(controller_url)
            program = acq_cycle.default_program(st.spec, st.measure_feed_mm_min,
                                                acceleration_mm_s2=st.measure_acceleration_mm_s2)
        except MebmError as exc:
            return CycleOutcome.failed(f"{type(exc).__name__}: {exc}")
        res = acq_cycle.run_cycle(driver, st.spec, program)
        trace = res.trace
        temp = trace.temperature_c if trace is not None and math.isfinite(trace.temperature_c) else None
        raw = {}
        if trace is not None:
            raw = dict(time_s=trace.time_s, motor_rev=trace.motor_rev, table_mm=trace.table_mm)
        # res.program: the round trip as run (passive mode: as observed, not as configured)
        common = dict(temperature_c=temp, feed_mm_min=res.program.feed_mm_min,
                      acceleration_mm_s2=res.program.acceleration_mm_s2,
                      trigger=trace.trigger if trace is not None else getattr(driver, "trigger", None), **raw)
        if not res.ok:
            return CycleOutcome(ok=False, reason=f"{res.reason_code}: {res.reason}", **common)
        return CycleOutcome(ok=True, uncertainty_um=res.uncertainty_um, round_trip=res.result, **common)
