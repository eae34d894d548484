"""The measurement cycle: acquire a round trip, validate it, compute the criteria and the decision.

:func:`run_cycle` never raises for a fault of the machine or the network: faults are
normal events and end the cycle as ``failed`` with a reason a technician can act on
(the driver has already sent the abort). No partial result is ever reported as a
valid measurement: a failed cycle carries no criteria. Usable from a thread
(:func:`run_cycle`) or an asyncio loop (:func:`run_cycle_async`).

A round trip whose trace has a stretch of travel without samples (a polled wire whose
host or network paused: nothing later can recover those samples) is run once more, if
mebm commanded it (``repeat_on_hole``). The result says so (``attempts``,
``repeated_after``), and so does the stored run; the first trace is refused, not used.
"""

from __future__ import annotations

import logging
import math
import time
from collections.abc import Sequence
from dataclasses import dataclass, field, replace

import numpy as np

from acquisition.driver.base import ControllerDriver
from acquisition.errors import AcquisitionError, IncompleteTraceError
from acquisition.types import AcquiredTrace, RoundTripProgram
from core.criteria import RoundTripResult, RoundTripSettings, analyze_round_trip
from core.criteria.uncertainty import Instruments
from core.dataset import AxisSpec, Run, RunSpec
from core.errors import MebmError, TraceError
from core.tbe import AxisDecision, MachiningTask, decide

log = logging.getLogger(__name__)

def reason_code(exc: BaseException) -> str:
    """A stable short code for the kind of failure (for the service, metrics and tests):
    the exception class's ``reason_code``."""
    if isinstance(exc, AcquisitionError):
        return type(exc).reason_code
    if isinstance(exc, TraceError):
        return "trace"
    return "error"


@dataclass(frozen=True)
class CycleResult:
    """Outcome of one measurement cycle. ``status`` is ``ok`` or ``failed``.

    ``uncertainty_um`` is the combined standard uncertainty of b̄ (GUM budget in
    ``result.budgets``; the acquisition's skew times speed enters as its sampling
    component in unlatched modes).
    """

    status: str
    controller: str
    axis: str
    program: RoundTripProgram
    reason: str | None = None
    reason_code: str | None = None
    trace: AcquiredTrace | None = None
    result: RoundTripResult | None = None
    decision: AxisDecision | None = None
    uncertainty_um: float = 0.0
    started_at: float = 0.0
    duration_s: float = 0.0
    error: BaseException | None = field(default=None, compare=False, repr=False)
    attempts: int = 1  # round trips run for this result (2: the first trace had a hole)
    repeated_after: str | None = None  # why the first round trip was refused, when repeated

    @property
    def ok(self) -> bool:
        return self.status == "ok"

    def to_dict(self) -> dict:
        out = {
            "status": self.status,
            "controller": self.controller,
            "axis": self.axis,
            "program": {
                "start_mm": self.program.start_mm, "end_mm": self.program.end_mm,
                "feed_mm_min": self.program.feed_mm_min,
                "acceleration_mm_s2": self.program.acceleration_mm_s2, "dwell_s": self.program.dwell_s,
            },
            "reason": self.reason,
            "reason_code": self.reason_code,
            "duration_s": self.duration_s,
            "attempts": self.attempts,
        }
        if self.repeated_after is not None:
            out["repeated_after"] = self.repeated_after
        if self.trace is not None:
            t = self.trace
            out["acquisition"] = {
                "protocol": t.protocol, "mode": t.mode, "latched": t.latched, "samples": len(t),
                "lost_samples": t.lost_samples, "sample_rate_hz": t.servo_rate_hz,
                "skew_uncertainty_um": t.skew_uncertainty_um, "clock_uncertainty_s": t.clock_uncertainty_s,
                "temperature_c": t.temperature_c,
                "samples_per_s": t.samples_per_s, "trigger": t.trigger,
            }
        if self.ok:
            out["uncertainty_um"] = self.uncertainty_um
            out["result"] = self.result.to_dict()
            if self.decision is not None:
                d = self.decision
                target = d.repair_target
                out["decision"] = {
                    "state": d.state.value, "binding_task": d.binding_task, "decision_rule": d.rule,
                    "backlash_limit_um": d.backlash_limit_um if math.isfinite(d.backlash_limit_um) else None,
                    "restore_below_um": target.restore_below_um if target is not None else None,
                    "restore_below_explanation": target.explanation if target is not None else None,
                    "message": d.message(),
                    "tasks": [{"name": a.task.name, "tbe_um": a.tbe_um, "tbe_uncertainty_um": a.tbe_uncertainty_um,
                               "tolerance_um": a.task.tolerance_um, "state": a.state.value,
                               "decision_rule": a.rule, "reason": a.reason,
                               "backlash_limit_um": a.backlash_limit_um if math.isfinite(a.backlash_limit_um) else None,
                               "backlash_limit_uncertainty_um": a.backlash_limit_uncertainty_um}
                              for a in d.assessments],
                }
        return out

    def to_run(self, file: str, *, utility_day: float | None = None, instruments: Instruments | None = None) -> Run:
        """The cycle as a ``mebm-dataset/1`` round-trip run; only valid measurements have one.
        ``instruments``: the scale and thermometer the budget was built with, stated in the
        run so that a re-analysis (``mebm analyze``) builds the same budget."""
        if not self.ok or self.trace is None:
            raise MebmError(f"cycle {self.status}: {self.reason}; a failed cycle is never stored as a measurement")
        t = self.trace
        extra = {
            "controller": self.controller, "acquisition_mode": t.mode, "latched": t.latched,
            "skew_uncertainty_um": t.skew_uncertainty_um, "clock_uncertainty_s": t.clock_uncertainty_s,
            "lost_samples": t.lost_samples,
            "sample_rate_hz": t.servo_rate_hz, "counter_first": int(t.counter[0]), "counter_last": int(t.counter[-1]),
            "travel_program_mm": [self.program.start_mm, self.program.end_mm], "trigger": t.trigger,
        }
        if self.repeated_after is not None:
            extra["repeated_after"] = self.repeated_after
        if instruments is not None:
            extra["instruments"] = instruments.to_dict()
        spec = RunSpec(file=file, kind="round_trip", axes=(self.axis,), feed_mm_min=self.program.feed_mm_min,
                       temperature_c=t.temperature_c if math.isfinite(t.temperature_c) else 20.0,
                       utility_day=utility_day, acceleration_mm_s2=self.program.acceleration_mm_s2, extra=extra)
        cols = {"time_s": t.time_s, f"{self.axis}_motor_rev": t.motor_rev, f"{self.axis}_table_mm": t.table_mm}
        return Run(spec, cols)


def validate_trace(trace: AcquiredTrace, program: RoundTripProgram, axis: AxisSpec,
                   useful_travel_mm: tuple[float, float] | None = None) -> None:
    """Raise :class:`IncompleteTraceError` unless the trace is a whole, continuous round trip.

    Checks: no NaN/inf; counter strictly increasing, and continuous for continuous modes
    (gaps only as many as the trace declares); both strokes present; the useful travel
    covered in each stroke.
    """
    n = len(trace)
    if n < 10:
        raise IncompleteTraceError(f"only {n} samples acquired; a round trip needs many more")
    for name in ("time_s", "motor_rev", "table_mm"):
        a = getattr(trace, name)
        bad = ~np.isfinite(a)
        if bad.any():
            raise IncompleteTraceError(f"{name} is NaN or inf at sample {int(np.argmax(bad))} ({int(bad.sum())} in all)")
    dc = np.diff(trace.counter)
    if np.any(dc <= 0):
        raise IncompleteTraceError(f"sample counter not increasing at sample {int(np.argmax(dc <= 0)) + 1}")
    # the driver may report more than the gaps show (samples lost before the first one that
    # arrived), never fewer
    # (a passive trace's rest before and after the round trip is polled, so decimated by design:
    # its driver counts the gaps of the controller's own trace only)
    if trace.mode in ("trace", "sync") and trace.trigger == "active" and int((dc - 1).sum()) > trace.lost_samples:
        raise IncompleteTraceError(
            f"counter has {int((dc - 1).sum())} missing values but the acquisition reported {trace.lost_samples}"
        )
    lo, hi = sorted((program.start_mm, program.end_mm))
    ulo, uhi = useful_travel_mm if useful_travel_mm is not None else (lo, hi)
    x = trace.table_mm
    turn = int(np.argmax(x) if program.end_mm > program.start_mm else np.argmin(x))
    out, back = x[: turn + 1], x[turn:]
    tol = max(0.05 * (hi - lo), 0.5)
    for name, part in (("outward", out), ("return", back)):
        if part.size < 5 or part.min() > ulo + tol or part.max() < uhi - tol:
            span = (float(part.min()), float(part.max())) if part.size else (float("nan"),) * 2
            raise IncompleteTraceError(
                f"the {name} stroke covers {span[0]:.2f}..{span[1]:.2f} mm, not the useful travel "
                f"{ulo:g}..{uhi:g} mm: the round trip was cut short"
            )


def _failed(driver, axis, program, exc, t0, wall0, trace=None) -> CycleResult:
    reason = str(exc)
    note = getattr(exc, "abort_note", None)
    if note:
        reason = f"{reason}; {note}"
    return CycleResult(status="failed", controller=driver.describe(), axis=axis.name, program=program,
                       reason=reason, reason_code=reason_code(exc), trace=trace, started_at=wall0,
                       duration_s=time.monotonic() - t0, error=exc)


def _evaluate(driver, axis, program, trace, tasks, useful_travel_mm, settings, t0, wall0,
              instruments: Instruments | None = None) -> CycleResult:
    program = trace.program  # passive mode: the round trip as observed (active: the one commanded)
    try:
        validate_trace(trace, program, axis, useful_travel_mm)
        result = analyze_round_trip(trace.time_s, trace.motor_rev, trace.table_mm, axis,
                                    useful_travel_mm=useful_travel_mm, settings=settings,
                                    uncertainty=(instruments or Instruments()).inputs(
                                        sampling_bound_um=trace.skew_uncertainty_um,
                                        clock_uncertainty_s=trace.clock_uncertainty_s,
                                        temperature_c=trace.temperature_c if math.isfinite(trace.temperature_c)
                                        else None))
        decision = decide(result.backlash_mean_um, tasks,
                          backlash_uncertainty_um=result.backlash_mean_uncertainty_um) if tasks else None
    except MebmError as exc:
        return _failed(driver, axis, program, exc, t0, wall0, trace)
    return CycleResult(status="ok", controller=driver.describe(), axis=axis.name, program=program, trace=trace,
                       result=result, decision=decision,
                       uncertainty_um=result.budgets["backlash_mean"].combined_um,
                       started_at=wall0, duration_s=time.monotonic() - t0)


# Allowance for the reversal transient beyond the loop's shortfall: the largest
# backlash worth measuring (0.5 mm), the transient margin the analysis skips (1 mm)
# and 1 mm of safety.
REVERSAL_ALLOWANCE_MM = 2.5


def default_program(axis: AxisSpec, feed_mm_min: float, *, acceleration_mm_s2: float = 500.0,
                    dwell_s: float = 0.2, overtravel_mm: float | None = None) -> RoundTripProgram:
    """A round trip over the axis' useful travel, extended just enough that the reversal
    transients fall outside it.

    A proportional loop stops short of a decelerating command by a/K² (the lag of a
    ramp-down); the dwell lets that decay by exp(-K dwell). Beyond that, the reversal
    needs the backlash plus the analysis' transient margin (``REVERSAL_ALLOWANCE_MM``).
    The default is that sum, at least 3 mm and never more than 10 % of the travel: a
    measurement should not take the axis far beyond the travel it was configured for.
    """
    lo, hi = axis.travel_mm
    if overtravel_mm is None:
        shortfall_mm = acceleration_mm_s2 / axis.position_gain_per_s**2 * math.exp(-axis.position_gain_per_s * dwell_s)
        overtravel_mm = min(max(shortfall_mm + REVERSAL_ALLOWANCE_MM, 3.0), 0.1 * (hi - lo))
    return RoundTripProgram(lo - overtravel_mm, hi + overtravel_mm, feed_mm_min,
                            acceleration_mm_s2=acceleration_mm_s2, dwell_s=dwell_s)


def sampling_hole(res: CycleResult, settings: RoundTripSettings = RoundTripSettings()) -> str | None:
    """Why ``res`` is worth running once more, or None: an active round trip refused for a
    stretch of travel without samples (two consecutive samples more than
    ``settings.max_gap_mm`` apart). A polled wire (latched or separate reads) has no
    buffer to recover such a stretch from; its cause, a paused host or network, passes. A
    failure of another kind (an encoder fault, samples the controller itself lost, a
    timeout) is not repeated: it would fail again or need a technician."""
    t = res.trace
    if res.ok or res.reason_code != "trace" or t is None or t.trigger != "active" or len(t) < 2:
        return None
    dx = np.abs(np.diff(t.table_mm))
    i = int(np.argmax(dx))
    if not dx[i] > settings.max_gap_mm:
        return None
    dt = float(t.time_s[i + 1] - t.time_s[i])
    return (f"{res.reason} (no sample for {dt:.3f} s over {dx[i]:.2f} mm at {t.table_mm[i]:.2f} mm: "
            f"the wire or the host paused)")


def _repeated(first: CycleResult, hole: str, second: CycleResult) -> CycleResult:
    log.warning("%s axis %s: round trip run again: %s", first.controller, first.axis, hole)
    reason = second.reason if second.ok else f"{second.reason} (the round trip was run twice; the first: {hole})"
    return replace(second, reason=reason, attempts=first.attempts + 1, repeated_after=hole,
                   started_at=first.started_at, duration_s=first.duration_s + second.duration_s)


def run_cycle(driver: ControllerDriver, axis: AxisSpec, program: RoundTripProgram, *,
              tasks: Sequence[MachiningTask] = (), useful_travel_mm: tuple[float, float] | None = None,
              settings: RoundTripSettings = RoundTripSettings(), repeat_on_hole: bool = True,
              instruments: Instruments | None = None) -> CycleResult:
    """One measurement cycle from a thread (runs its own event loop). Never raises for faults.
    ``repeat_on_hole``: run the round trip once more if its trace has a hole
    (:func:`sampling_hole`). ``instruments``: the axis' linear scale and thermometer, for
    the uncertainty budget (None: the defaults, a glass scale and a Pt100 of class B)."""
    res = _run_once(driver, axis, program, tasks, useful_travel_mm, settings, instruments)
    hole = sampling_hole(res, settings) if repeat_on_hole else None
    if hole is None:
        return res
    return _repeated(res, hole, _run_once(driver, axis, program, tasks, useful_travel_mm, settings, instruments))


def _run_once(driver, axis, program, tasks, useful_travel_mm, settings, instruments) -> CycleResult:
    t0, wall0 = time.monotonic(), time.time()
    try:
        trace = driver.acquire(program, axis)
    except MebmError as exc:
        return _failed(driver, axis, program, exc, t0, wall0)
    return _evaluate(driver, axis, program, trace, tasks, useful_travel_mm, settings, t0, wall0, instruments)


async def run_cycle_async(driver: ControllerDriver, axis: AxisSpec, program: RoundTripProgram, *,
                          tasks: Sequence[MachiningTask] = (), useful_travel_mm: tuple[float, float] | None = None,
                          settings: RoundTripSettings = RoundTripSettings(),
                          repeat_on_hole: bool = True, instruments: Instruments | None = None) -> CycleResult:
    """:func:`run_cycle` for callers already inside an asyncio loop."""
    res = await _run_once_async(driver, axis, program, tasks, useful_travel_mm, settings, instruments)
    hole = sampling_hole(res, settings) if repeat_on_hole else None
    if hole is None:
        return res
    again = await _run_once_async(driver, axis, program, tasks, useful_travel_mm, settings, instruments)
    return _repeated(res, hole, again)


async def _run_once_async(driver, axis, program, tasks, useful_travel_mm, settings, instruments) -> CycleResult:
    t0, wall0 = time.monotonic(), time.time()
    try:
        trace = await driver.acquire_async(program, axis)
    except MebmError as exc:
        return _failed(driver, axis, program, exc, t0, wall0)
    return _evaluate(driver, axis, program, trace, tasks, useful_travel_mm, settings, t0, wall0, instruments)
