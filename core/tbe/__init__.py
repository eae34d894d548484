"""TBE from backlash (Eqs. 7-11), its inverse, and the maintenance decision."""

from core.tbe.decision import (
    DECISION_RULES,
    DEFAULT_RULE,
    AxisDecision,
    MachiningTask,
    State,
    TaskAssessment,
    decide,
    state_of,
)
from core.tbe.repair import RepairTarget, repair_target, stored_repair_target
from core.tbe.formulas import (
    backlash_limit_um,
    circle_delay_s,
    circle_steady_lag_um,
    tbe_circle_um,
    tbe_line_um,
)

__all__ = [
    "DECISION_RULES", "DEFAULT_RULE", "AxisDecision", "MachiningTask", "RepairTarget", "State", "TaskAssessment",
    "decide", "state_of", "repair_target", "stored_repair_target",
    "backlash_limit_um", "circle_delay_s", "circle_steady_lag_um", "tbe_circle_um", "tbe_line_um",
]
