"""Mechanical-chain accuracy from a round trip: backlash b(x) and ISO 3408-3 lead criteria."""

from core.criteria.lead import (
    CRITERION_NAMES, CRITERION_SYMBOLS, LeadCriteria, criterion_label, lead_criteria, max_window_band,
)
from core.criteria.roundtrip import BacklashProfile, RoundTripResult, RoundTripSettings, analyze_round_trip
from core.criteria.segmentation import SegmentationSettings, Stroke, find_strokes

__all__ = [
    "BacklashProfile", "CRITERION_NAMES", "CRITERION_SYMBOLS", "LeadCriteria", "RoundTripResult", "RoundTripSettings",
    "SegmentationSettings", "Stroke", "analyze_round_trip", "criterion_label", "find_strokes", "lead_criteria", "max_window_band",
]
