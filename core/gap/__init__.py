"""Sim-to-real gap diagnosis: where the nominal model misses a machine, which effect
explains it, and by how much adding that effect closes the gap on held-out runs.

``diagnose(dataset) -> GapReport`` (``to_dict()`` is the spec's ``mebm-gap/1`` JSON,
``text()`` the human report). The effect families are plugins (``core.gap.families``);
the search, the selection, the evidence and the report reach them through that registry.
``core.gap_benchmark`` scores the diagnosis on generated datasets whose effect is
withheld. See docs/gap-diagnosis.md for the method and its thresholds.
"""

from core.gap.data import GapError, Split, choose_split, prepare_runs
from core.gap.diagnose import EFFECTS, GapSettings, diagnose
from core.gap.report import FORMAT, Candidate, GapReport, Where

__all__ = [
    "EFFECTS", "FORMAT", "Candidate", "GapError", "GapReport", "GapSettings", "Split", "Where", "choose_split",
    "diagnose", "prepare_runs",
]
