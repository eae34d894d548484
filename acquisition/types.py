"""Types shared by the drivers, the simulated controllers and the cycle."""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from enum import IntEnum

import numpy as np

from core.errors import InputError, require_finite, require_positive


class AxisState(IntEnum):
    """Axis/program state as exposed by the controller (same codes on Modbus and CANopen)."""

    IDLE = 0
    RUNNING = 1
    DONE = 2
    ABORTED = 3
    FAULT = 4


class Command(IntEnum):
    """Control commands (Modbus COMMAND register, CANopen object 0x2001)."""

    NONE = 0
    START = 1
    ABORT = 2
    ACKNOWLEDGE = 3


@dataclass(frozen=True)
class RoundTripProgram:
    """The programmed round trip: start_mm -> end_mm -> start_mm at feed_mm_min.

    ``dwell_s`` is the stop at the reversal. Positions are table coordinates in mm.
    """

    start_mm: float
    end_mm: float
    feed_mm_min: float
    acceleration_mm_s2: float = 500.0
    dwell_s: float = 0.2

    def __post_init__(self) -> None:
        require_finite("start_mm", self.start_mm)
        require_finite("end_mm", self.end_mm)
        require_positive("feed_mm_min", self.feed_mm_min)
        require_positive("acceleration_mm_s2", self.acceleration_mm_s2)
        if not (math.isfinite(self.dwell_s) and self.dwell_s >= 0):
            raise InputError(f"dwell_s (={self.dwell_s}) must be >= 0")
        if abs(self.end_mm - self.start_mm) < 1e-3:
            raise InputError(f"travel (start_mm={self.start_mm}, end_mm={self.end_mm}) must be at least 1 µm")

    @property
    def travel_mm(self) -> float:
        return abs(self.end_mm - self.start_mm)

    @property
    def speed_mm_s(self) -> float:
        return self.feed_mm_min / 60.0

    @property
    def duration_s(self) -> float:
        """Machine time of the whole round trip (trapezoidal profile each way, plus the dwell)."""
        v, a, d = self.speed_mm_s, self.acceleration_mm_s2, self.travel_mm
        if d * a >= v * v:  # cruise phase reached
            one_way = d / v + v / a
        else:
            one_way = 2.0 * math.sqrt(d / a)
        return 2.0 * one_way + 3.0 * self.dwell_s  # dwell before, between and after (an upper bound)


@dataclass(frozen=True)
class ControllerStatus:
    """One read of the controller's state block."""

    state: AxisState
    fault_code: int = 0
    temperature_c: float = float("nan")
    servo_rate_hz: float = float("nan")


@dataclass(frozen=True)
class SampleBlock:
    """Samples delivered by one drain of the wire, in controller order.

    ``counter`` is the controller's sample (servo cycle or SYNC) counter, unwrapped to int64.
    ``time_s`` is the sample time when the wire knows it (else the base class derives it
    from the counter and the servo rate). ``finished``: the program has ended and this
    block holds its last sample. ``skew_s``: worst-case time between the motor and
    table readings of each sample (0 when latched together). ``clock_s``: bound on the
    error of ``time_s`` (a polled sample is stamped at the middle of its request, not
    when the controller latched it; 0 when the wire carries the controller's time).
    """

    counter: np.ndarray
    motor_rev: np.ndarray
    table_mm: np.ndarray
    finished: bool = False
    time_s: np.ndarray | None = None
    skew_s: float = 0.0
    clock_s: float = 0.0
    caught_up: bool = True  # False: more samples are already waiting, drain again at once
    running: np.ndarray | None = None  # passive mode: the controller's "program running" flag per sample
    run_start: bool = False  # passive mode: the first sample is the first of the controller's program run

    @staticmethod
    def empty(finished: bool = False) -> "SampleBlock":
        z = np.zeros(0)
        return SampleBlock(np.zeros(0, dtype=np.int64), z, z, finished)

    def __len__(self) -> int:
        return int(self.counter.shape[0])


@dataclass(frozen=True)
class AcquiredTrace:
    """Everything the drivers acquired in one round trip, in physical units.

    ``latched``: motor and table values of each sample were latched in the same
    controller cycle. When False (``mode == "separate"``), ``skew_uncertainty_um`` is
    the worst-case skew between the two readings times the programmed speed, and must
    be carried as an uncertainty of the backlash.
    """

    protocol: str
    mode: str
    time_s: np.ndarray
    counter: np.ndarray
    motor_rev: np.ndarray
    table_mm: np.ndarray
    temperature_c: float
    latched: bool
    skew_uncertainty_um: float
    lost_samples: int
    servo_rate_hz: float
    program: RoundTripProgram
    wall_time_s: float = float("nan")
    drain_time_s: float = float("nan")  # wall time from the first to the last drained block
    trigger: str = "active"  # "active": mebm started the round trip; "passive": the CNC did, mebm detected it
    notes: tuple[str, ...] = field(default_factory=tuple)
    clock_uncertainty_s: float = 0.0  # bound on the error of time_s (polled samples: half the longest request)

    def __len__(self) -> int:
        return int(self.time_s.shape[0])

    @property
    def samples_per_s(self) -> float:
        """Samples acquired per second of wall-clock time while draining."""
        return len(self) / self.drain_time_s if self.drain_time_s > 0 else float("nan")
