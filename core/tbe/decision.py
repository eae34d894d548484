"""Machining tasks and the maintenance decision for one axis (Sections 5.2-5.3).

A task is what the shop makes with the axis: a circle (radius, feed) or a line
(angle, feed), the axis gain K = k_a k_p and the permissible error. The decision
maps the measured mean backlash to the TBE of every task, names the binding task,
and gives the backlash the mechanical chain must be restored to.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from enum import Enum

from core.errors import InputError, ModelDomainError, require_finite, require_positive
from core.tbe.formulas import backlash_limit_um, circle_steady_lag_um, tbe_circle_um, tbe_line_um


class State(str, Enum):
    OK = "OK"
    WARNING = "WARNING"
    ALARM = "ALARM"


@dataclass(frozen=True)
class MachiningTask:
    """One machining task of an axis. ``profile`` is ``circle`` (needs ``radius_mm``)
    or ``line`` (needs ``angle_deg``, to the reversely engaged axis)."""

    name: str
    profile: str
    feed_mm_min: float
    gain_per_s: float
    tolerance_um: float
    radius_mm: float | None = None
    angle_deg: float | None = None

    def __post_init__(self) -> None:
        if self.profile not in ("circle", "line"):
            raise InputError(f"task {self.name!r}: profile (={self.profile!r}) must be 'circle' or 'line'")
        require_positive(f"task {self.name!r}: feed_mm_min", self.feed_mm_min)
        require_positive(f"task {self.name!r}: gain_per_s", self.gain_per_s)
        require_positive(f"task {self.name!r}: tolerance_um", self.tolerance_um)
        if self.profile == "circle":
            if self.radius_mm is None:
                raise InputError(f"task {self.name!r}: a circle needs radius_mm")
            require_positive(f"task {self.name!r}: radius_mm", self.radius_mm)
        else:
            if self.angle_deg is None:
                raise InputError(f"task {self.name!r}: a line needs angle_deg")
            a = require_finite(f"task {self.name!r}: angle_deg", self.angle_deg)
            if not -90.0 < a < 90.0:
                raise InputError(f"task {self.name!r}: angle_deg (={a}) must be in (-90, 90)")

    def tbe_um(self, backlash_um):
        """TBE in µm for backlash width(s) in µm (Eq. 8 for circles, Eq. 7 for lines)."""
        if self.profile == "circle":
            return tbe_circle_um(backlash_um, self.radius_mm, self.feed_mm_min, self.gain_per_s)
        return tbe_line_um(backlash_um, self.angle_deg, self.feed_mm_min, self.gain_per_s)

    def backlash_limit_um(self) -> float:
        """Largest permissible backlash in µm; ``inf`` when the task never reaches its tolerance."""
        try:
            return backlash_limit_um(
                self.tolerance_um,
                feed_mm_min=self.feed_mm_min,
                gain_per_s=self.gain_per_s,
                radius_mm=self.radius_mm if self.profile == "circle" else None,
                angle_deg=self.angle_deg if self.profile == "line" else None,
            )
        except ModelDomainError as exc:
            if "met by any backlash" in str(exc):
                return math.inf
            raise

    def steady_lag_um(self) -> float:
        """For circles: how far the backlash-free loop already runs inside the circle (µm)."""
        if self.profile != "circle":
            return 0.0
        return circle_steady_lag_um(self.radius_mm, self.feed_mm_min, self.gain_per_s)


@dataclass(frozen=True)
class TaskAssessment:
    task: MachiningTask
    tbe_um: float
    backlash_limit_um: float
    state: State

    @property
    def utilisation(self) -> float:
        """TBE as a fraction of the permissible error."""
        return self.tbe_um / self.task.tolerance_um


@dataclass(frozen=True)
class AxisDecision:
    """The maintenance verdict for one axis at one measured backlash."""

    backlash_um: float
    warning_fraction: float
    assessments: tuple[TaskAssessment, ...]
    binding_task: str
    state: State
    backlash_limit_um: float

    def message(self) -> str:
        binding = next(a for a in self.assessments if a.task.name == self.binding_task)
        head = (
            f"{self.state.value}: mean backlash {self.backlash_um:.1f} µm gives TBE "
            f"{binding.tbe_um:.2f} µm on task {self.binding_task!r} "
            f"(tolerance {binding.task.tolerance_um:g} µm)"
        )
        if self.state is State.ALARM:
            return head + f"; restore the chain to a backlash below {self.backlash_limit_um:.1f} µm"
        if math.isinf(self.backlash_limit_um):
            return head + "; no task limits the backlash"
        return head + f"; backlash limit {self.backlash_limit_um:.1f} µm"


def decide(
    backlash_um: float, tasks: Sequence[MachiningTask], *, warning_fraction: float = 0.9
) -> AxisDecision:
    """TBE per task, the binding task (highest TBE/tolerance), and the state.

    ALARM when a TBE exceeds its tolerance, WARNING above ``warning_fraction`` of it,
    else OK. The backlash limit is the smallest over the tasks.
    """
    b = require_finite("backlash_um", backlash_um)
    if b < 0:
        raise InputError(f"backlash_um (={b}) must be >= 0")
    if not 0.0 < warning_fraction <= 1.0:
        raise InputError(f"warning_fraction (={warning_fraction}) must be in (0, 1]")
    if not tasks:
        raise InputError("an axis needs at least one machining task to decide on")
    names = [t.name for t in tasks]
    if len(set(names)) != len(names):
        raise InputError(f"task names must be unique, got {names}")
    out = []
    for task in tasks:
        tbe = float(task.tbe_um(b))
        if tbe > task.tolerance_um:
            state = State.ALARM
        elif tbe > warning_fraction * task.tolerance_um:
            state = State.WARNING
        else:
            state = State.OK
        out.append(TaskAssessment(task, tbe, task.backlash_limit_um(), state))
    binding = max(out, key=lambda a: a.utilisation)
    worst = max((a.state for a in out), key=[State.OK, State.WARNING, State.ALARM].index)
    return AxisDecision(
        backlash_um=b,
        warning_fraction=warning_fraction,
        assessments=tuple(out),
        binding_task=binding.task.name,
        state=worst,
        backlash_limit_um=min(a.backlash_limit_um for a in out),
    )
