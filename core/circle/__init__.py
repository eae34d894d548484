"""Circular tests (ISO 230-4): the direct measurement of the contouring error.

Two axes of a plane run a full circle in both directions; :func:`analyze` computes
ISO 230-4's figures with their uncertainty budgets (G by least squares and minimum
zone, H, F, centre offset, the reversal spikes). The spikes are compared with Eq. 8 at
the axis' backlash (:mod:`core.circle.agreement`), and a test at a task's own radius
and feed is judged against the task's tolerance (:mod:`core.circle.decision`).
"""

from core.circle.agreement import Agreement, compare_with_backlash
from core.circle.decision import CircleDecision, decide_circle
from core.circle.figures import DEFAULT_SPIKE_WINDOW_DEG, CircleFigures, Spike, analyze
from core.circle.io import from_json, to_json
from core.circle.test import (
    DIRECTIONS,
    INSTRUMENT_KINDS,
    QUADRANTS_DEG,
    CirclePass,
    CircularTest,
    Instrument,
    pass_from_positions,
    test_from_positions,
)

__all__ = [
    "DEFAULT_SPIKE_WINDOW_DEG", "DIRECTIONS", "INSTRUMENT_KINDS", "QUADRANTS_DEG",
    "Agreement", "CircleDecision", "CircleFigures", "CirclePass", "CircularTest", "Instrument", "Spike",
    "analyze", "compare_with_backlash", "decide_circle", "from_json", "pass_from_positions", "test_from_positions", "to_json",
]
