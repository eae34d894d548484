"""Machining tasks and the maintenance decision for one axis (Sections 5.2-5.3).

A task is what the shop makes with the axis: a circle (radius, feed) or a line
(angle, feed), the axis gain K = k_a k_p and the permissible error. The decision
maps the measured mean backlash to the TBE of every task, names the binding task,
and gives the backlash the mechanical chain must be restored to.

Decision rules (ISO 14253-1, ILAC-G8:2019), with U the expanded uncertainty of the
TBE (the backlash's, through the derivative of Eq. 7/8):

- ``simple``: ALARM when TBE > tolerance, WARNING when TBE > warning threshold, else OK;
- ``guarded`` (default): ALARM only when TBE - U > tolerance (nonconformity proven),
  OK only when TBE + U <= warning threshold (conformity proven), otherwise WARNING,
  "within uncertainty of the limit" where the simple rule would have said otherwise.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, replace
from functools import lru_cache
from enum import Enum

from core.errors import InputError, ModelDomainError, require_finite, require_positive
from core.tbe.formulas import backlash_limit_um, circle_steady_lag_um, tbe_circle_um, tbe_line_um
from core.tbe.repair import RepairTarget, repair_target


class State(str, Enum):
    OK = "OK"
    WARNING = "WARNING"
    ALARM = "ALARM"


DECISION_RULES = ("simple", "guarded")
DEFAULT_RULE = "guarded"
WITHIN_UNCERTAINTY = "within uncertainty of the limit"


def _check_rule(rule: str, where: str = "decision_rule") -> str:
    if rule not in DECISION_RULES:
        raise InputError(f"{where} (={rule!r}) must be one of {DECISION_RULES}")
    return rule


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
    # Type B half-width of how well K of the real loop is known (relative, rectangular):
    # the backlash limit's uncertainty
    gain_rel_uncertainty: float = 0.01
    decision_rule: str | None = None  # None: the axis' rule

    def __post_init__(self) -> None:
        if self.decision_rule is not None:
            _check_rule(self.decision_rule, f"task {self.name!r}: decision_rule")
        g = require_finite(f"task {self.name!r}: gain_rel_uncertainty", self.gain_rel_uncertainty)
        if not 0.0 <= g < 1.0:
            raise InputError(f"task {self.name!r}: gain_rel_uncertainty (={g}) must be in [0, 1)")
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
        """Largest permissible backlash in µm; ``inf`` when the task never reaches its tolerance.
        Memoised per task (a task is frozen): the prognosis' bisection asks for it ~40 times."""
        return _limit_um(self)

    def tbe_uncertainty_um(self, backlash_um: float, backlash_uncertainty_um: float) -> float:
        """Expanded uncertainty of the TBE from that of the backlash: |dTBE/db| U_b
        (central difference; one-sided at b = 0 and at the edge of Eq. 8's domain).
        Where the slope changes much within ±U_b (Eq. 7 near b = 0 goes as √b) the
        secant over [b - U_b, b + U_b] is taken instead, which bounds the change."""
        u = float(backlash_uncertainty_um)
        if not u > 0:
            return 0.0
        b = float(backlash_um)
        centre = float(self.tbe_um(b))
        lo_b = max(0.0, b - u)
        lo = float(self.tbe_um(lo_b))
        try:
            hi_b, hi = b + u, float(self.tbe_um(b + u))
        except ModelDomainError:
            hi_b, hi = b, centre
        secant = (hi - lo) / (hi_b - lo_b) * u if hi_b > lo_b else 0.0
        h = max(1e-6, 1e-4 * u)
        try:
            slope = (float(self.tbe_um(b + h)) - float(self.tbe_um(max(0.0, b - h)))) / (b + h - max(0.0, b - h))
        except ModelDomainError:
            slope = (centre - float(self.tbe_um(max(0.0, b - h)))) / (b - max(0.0, b - h)) if b > 0 else 0.0
        return max(abs(slope) * u, abs(secant))

    def backlash_limit_uncertainty_um(self) -> float:
        """Expanded (k = 2) uncertainty of the backlash limit from ``gain_rel_uncertainty``
        (rectangular half-width), by the limits at K (1 ± δ); 0 for an infinite limit."""
        return _limit_uncertainty_um(self)

    def steady_lag_um(self) -> float:
        """For circles: how far the backlash-free loop already runs inside the circle (µm)."""
        if self.profile != "circle":
            return 0.0
        return circle_steady_lag_um(self.radius_mm, self.feed_mm_min, self.gain_per_s)


@lru_cache(maxsize=1024)
def _limit_um(task: MachiningTask) -> float:
    try:
        return backlash_limit_um(
            task.tolerance_um,
            feed_mm_min=task.feed_mm_min,
            gain_per_s=task.gain_per_s,
            radius_mm=task.radius_mm if task.profile == "circle" else None,
            angle_deg=task.angle_deg if task.profile == "line" else None,
        )
    except ModelDomainError as exc:
        if "met by any backlash" in str(exc):
            return math.inf
        raise


@lru_cache(maxsize=1024)
def _limit_uncertainty_um(task: MachiningTask) -> float:
    limit = task.backlash_limit_um()
    if not math.isfinite(limit) or task.gain_rel_uncertainty == 0:
        return 0.0
    out = []
    for sign in (1.0, -1.0):
        try:
            out.append(replace(task, gain_per_s=task.gain_per_s * (1 + sign * task.gain_rel_uncertainty))
                       .backlash_limit_um())
        except ModelDomainError:
            continue
    finite = [x for x in out if math.isfinite(x)]
    if not finite:
        return 0.0
    half_width = max(abs(x - limit) for x in finite)
    return 2.0 * half_width / math.sqrt(3.0)


@dataclass(frozen=True)
class TaskAssessment:
    task: MachiningTask
    tbe_um: float
    backlash_limit_um: float
    state: State
    tbe_uncertainty_um: float = 0.0  # expanded, k = 2
    backlash_limit_uncertainty_um: float = 0.0  # expanded, k = 2
    rule: str = DEFAULT_RULE
    reason: str = ""

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
    backlash_uncertainty_um: float = 0.0  # expanded, k = 2
    rule: str = DEFAULT_RULE

    @property
    def repair_target(self) -> RepairTarget | None:
        """What a repair must restore the backlash below (None: no task limits it)."""
        return repair_target(self.backlash_limit_um, self.warning_fraction)

    def message(self) -> str:
        binding = next(a for a in self.assessments if a.task.name == self.binding_task)
        unc = f" ± {binding.tbe_uncertainty_um:.2f}" if binding.tbe_uncertainty_um > 0 else ""
        b_unc = f" ± {self.backlash_uncertainty_um:.1f}" if self.backlash_uncertainty_um > 0 else ""
        head = (
            f"{self.state.value}: mean backlash {self.backlash_um:.1f}{b_unc} µm gives TBE "
            f"{binding.tbe_um:.2f}{unc} µm (k = 2) on task {self.binding_task!r} "
            f"(tolerance {binding.task.tolerance_um:g} µm, {binding.rule} decision rule"
            + (f": {binding.reason}" if binding.reason == WITHIN_UNCERTAINTY else "") + ")"
        )
        if self.state is State.ALARM:
            target = self.repair_target
            return head + (f"; {target.sentence()}" if target is not None else "; restore the backlash")
        if math.isinf(self.backlash_limit_um):
            return head + "; no task limits the backlash"
        return head + f"; backlash limit {self.backlash_limit_um:.1f} µm"


def state_of(error_um: float, uncertainty_um: float, tolerance_um: float, warning_um: float,
             rule: str) -> tuple[State, str]:
    """The state of an error (µm, expanded uncertainty ``uncertainty_um``) against a
    tolerance and a warning threshold by ``rule`` (see the module docstring), and the
    reason when it is not OK. Shared by every decision on a machining error: the TBE
    predicted from the backlash, and the one a circular test measures."""
    tbe, u, tolerance, warning = error_um, uncertainty_um, tolerance_um, warning_um
    _check_rule(rule)
    if tbe > tolerance:
        simple = State.ALARM
    elif tbe > warning:
        simple = State.WARNING
    else:
        simple = State.OK
    if rule == "simple":
        return simple, "" if simple is State.OK else (
            "above the tolerance" if simple is State.ALARM else "above the warning threshold")
    if tbe - u > tolerance:
        return State.ALARM, "above the tolerance by more than the uncertainty"
    if tbe + u <= warning:
        return State.OK, ""
    if simple is State.WARNING and tbe - u > warning and tbe + u <= tolerance:
        return State.WARNING, "above the warning threshold"
    return State.WARNING, WITHIN_UNCERTAINTY


def decide(
    backlash_um: float, tasks: Sequence[MachiningTask], *, warning_fraction: float = 0.9,
    backlash_uncertainty_um: float = 0.0, rule: str = DEFAULT_RULE,
) -> AxisDecision:
    """TBE per task with its uncertainty, the binding task (highest TBE/tolerance), and
    the state by the decision rule (``simple`` or ``guarded``; a task's own
    ``decision_rule`` overrides the axis' ``rule``).

    ``backlash_uncertainty_um`` is the expanded (k = 2) uncertainty of the backlash.
    The backlash limit is the smallest over the tasks.
    """
    b = require_finite("backlash_um", backlash_um)
    if b < 0:
        raise InputError(f"backlash_um (={b}) must be >= 0")
    u_b = require_finite("backlash_uncertainty_um", backlash_uncertainty_um)
    if u_b < 0:
        raise InputError(f"backlash_uncertainty_um (={u_b}) must be >= 0")
    _check_rule(rule)
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
        u_tbe = task.tbe_uncertainty_um(b, u_b)
        task_rule = task.decision_rule or rule
        state, reason = state_of(tbe, u_tbe, task.tolerance_um, warning_fraction * task.tolerance_um, task_rule)
        out.append(TaskAssessment(task, tbe, task.backlash_limit_um(), state, tbe_uncertainty_um=u_tbe,
                                  backlash_limit_uncertainty_um=task.backlash_limit_uncertainty_um(),
                                  rule=task_rule, reason=reason))
    binding = max(out, key=lambda a: a.utilisation)
    worst = max((a.state for a in out), key=[State.OK, State.WARNING, State.ALARM].index)
    return AxisDecision(
        backlash_um=b,
        warning_fraction=warning_fraction,
        assessments=tuple(out),
        binding_task=binding.task.name,
        state=worst,
        backlash_limit_um=min(a.backlash_limit_um for a in out),
        backlash_uncertainty_um=u_b,
        rule=rule,
    )
