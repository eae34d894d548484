"""A decision from the direct measurement: a circular test at a task's own radius and feed
IS that task's machining error.

The axis' measured TBE (its largest reversal spike, with its U) is judged against the
task's tolerance by the same rule and guard bands as the decision from the backlash
(:func:`core.tbe.decision.state_of`). Tasks whose radius or feed differ from the test's
by more than the relative tolerances are not judged: a spike depends on both.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, replace

from core.circle.figures import CircleFigures
from core.errors import InputError
from core.tbe.decision import DECISION_RULES, DEFAULT_RULE, WITHIN_UNCERTAINTY, MachiningTask, State, state_of

_ORDER = [State.OK, State.WARNING, State.ALARM]


@dataclass(frozen=True)
class CircleDecision:
    """The state of ``task`` on the error the circular test measured (expanded U, k = 2)."""

    state: State
    task: str
    axis: str
    error_um: float
    uncertainty_um: float
    tolerance_um: float
    warning_um: float
    rule: str
    reason: str
    circular_deviation_um: float
    circular_deviation_uncertainty_um: float
    spike: str = ""  # which reversal is the largest, "<direction>@<quadrant>°"
    judged_tasks: tuple[str, ...] = ()  # every task the test matched (the decision names the worst)

    def message(self) -> str:
        why = f": {self.reason}" if self.reason == WITHIN_UNCERTAINTY else ""
        return (f"{self.state.value}: the circular test measures TBE {self.error_um:.2f} ± {self.uncertainty_um:.2f} µm "
                f"(k = 2) on axis {self.axis} ({self.spike}) for task {self.task!r} (tolerance {self.tolerance_um:g} "
                f"µm, {self.rule} decision rule{why}); circular deviation G {self.circular_deviation_um:.2f} ± "
                f"{self.circular_deviation_uncertainty_um:.2f} µm")

    def to_dict(self) -> dict:
        return {
            "state": self.state.value,
            "task": self.task,
            "axis": self.axis,
            "error_um": self.error_um,
            "uncertainty_um": self.uncertainty_um,
            "tolerance_um": self.tolerance_um,
            "warning_um": self.warning_um,
            "rule": self.rule,
            "reason": self.reason,
            "circular_deviation_um": self.circular_deviation_um,
            "circular_deviation_uncertainty_um": self.circular_deviation_uncertainty_um,
            "spike": self.spike,
            "judged_tasks": list(self.judged_tasks),
            "message": self.message(),
        }


def matching_tasks(figures: CircleFigures, tasks: Sequence[MachiningTask], *, radius_tolerance_rel: float = 0.02,
                   feed_tolerance_rel: float = 0.02) -> list[MachiningTask]:
    """The circle tasks whose radius and feed are the test's within the relative tolerances."""
    for name, v in (("radius_tolerance_rel", radius_tolerance_rel), ("feed_tolerance_rel", feed_tolerance_rel)):
        if not (isinstance(v, (int, float)) and math.isfinite(v) and 0 <= v < 1):
            raise InputError(f"{name} (={v!r}) must be in [0, 1)")
    out = []
    for t in tasks:
        if not isinstance(t, MachiningTask):
            raise InputError(f"tasks must be MachiningTask objects, got {type(t).__name__}")
        if t.profile != "circle":
            continue
        if (abs(figures.radius_mm - t.radius_mm) <= radius_tolerance_rel * t.radius_mm
                and abs(figures.feed_mm_min - t.feed_mm_min) <= feed_tolerance_rel * t.feed_mm_min):
            out.append(t)
    return out


def decide_circle(figures: CircleFigures, tasks: Sequence[MachiningTask], *, axis: str,
                  warning_fraction: float = 0.9, rule: str = DEFAULT_RULE, radius_tolerance_rel: float = 0.02,
                  feed_tolerance_rel: float = 0.02) -> CircleDecision | None:
    """The state of each circle task the test matches, on ``axis``' worst reversal spike
    (the spike whose state is worst, then the highest); the worst task (then the most
    used of its tolerance) is returned, None if no task matched.
    A task's own ``decision_rule`` overrides ``rule``."""
    if not isinstance(figures, CircleFigures):
        raise InputError(f"decide_circle needs CircleFigures (from analyze), got {type(figures).__name__}")
    if rule not in DECISION_RULES:
        raise InputError(f"rule (={rule!r}) must be one of {DECISION_RULES}")
    if not (isinstance(warning_fraction, (int, float)) and 0.0 < warning_fraction <= 1.0):
        raise InputError(f"warning_fraction (={warning_fraction!r}) must be in (0, 1]")
    axis = str(axis).strip().lower()
    spikes = figures.spikes_of(axis)
    if not spikes:
        raise InputError(f"axis (={axis!r}) does not reverse in this circular test (its plane is "
                         f"{figures.plane}): give one of its two axes")
    matched = matching_tasks(figures, tasks, radius_tolerance_rel=radius_tolerance_rel,
                             feed_tolerance_rel=feed_tolerance_rel)
    if not matched:
        return None
    out = []
    for t in matched:
        task_rule = t.decision_rule or rule
        warning = warning_fraction * t.tolerance_um
        # the axis' TBE is its worst reversal: the spike whose state is worst, then the highest
        judged = [(state_of(s.height_um, s.height_uncertainty_um, t.tolerance_um, warning, task_rule), s)
                  for s in spikes]
        (state, reason), worst = max(judged, key=lambda j: (_ORDER.index(j[0][0]), j[1].height_um))
        out.append(CircleDecision(
            state=state, task=t.name, axis=axis, error_um=worst.height_um, uncertainty_um=worst.height_uncertainty_um,
            tolerance_um=t.tolerance_um, warning_um=warning, rule=task_rule, reason=reason,
            circular_deviation_um=figures.circular_deviation_um,
            circular_deviation_uncertainty_um=figures.circular_deviation_uncertainty_um,
            spike=f"{worst.direction}@{worst.quadrant_deg:g}°"))
    best = max(out, key=lambda d: (_ORDER.index(d.state), d.error_um / d.tolerance_um))
    return replace(best, judged_tasks=tuple(d.task for d in out))
