"""Measurement uncertainty of a round trip after the GUM (JCGM 100:2008).

Every result carries a budget per quantity (b̄ and each lead criterion of each stroke):
the standard uncertainty of each component, their root sum of squares (the combined
standard uncertainty u_c, components taken as uncorrelated) and the expanded
uncertainty U = k u_c with k = 2 (about 95 % coverage for a near-normal result).

Components (standard uncertainties, µm):

- ``resolution``: the encoders' quantisation q, rectangular: q/√12 per encoder (Type B);
- ``noise``: the scatter of l_a - l_0 about its smooth part, estimated from the data
  (robust, from second differences), reduced by the number of samples averaged (Type A);
- ``sampling``: a bound a on the sampling error (latch jitter x speed in trace/latched
  mode, skew x speed in separate mode), rectangular: a/√3 (Type B);
- ``transmission``: for e_p only, the relative tolerance of the configured k_a over the
  useful travel, rectangular (Type B);
- ``repeatability`` and ``normalisation``: once history exists, the scatter of recent
  cycles at similar temperature and the uncertainty of the 20 °C normalisation
  (β and the thermometer); given by the caller (the service), 0 when absent.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

from core.errors import InputError

COVERAGE_FACTOR = 2.0


@dataclass(frozen=True)
class UncertaintyComponent:
    name: str
    standard_um: float
    note: str = ""

    def to_dict(self) -> dict:
        return {"name": self.name, "standard_um": self.standard_um, "note": self.note}


@dataclass(frozen=True)
class UncertaintyBudget:
    """Budget of one quantity. ``combined_um`` is u_c, ``expanded_um`` U = k u_c."""

    quantity: str
    components: tuple[UncertaintyComponent, ...]
    coverage_factor: float = COVERAGE_FACTOR

    @property
    def combined_um(self) -> float:
        return math.sqrt(sum(c.standard_um**2 for c in self.components))

    @property
    def expanded_um(self) -> float:
        return self.coverage_factor * self.combined_um

    def with_components(self, *extra: UncertaintyComponent) -> "UncertaintyBudget":
        return UncertaintyBudget(self.quantity, self.components + tuple(extra), self.coverage_factor)

    def to_dict(self) -> dict:
        return {
            "quantity": self.quantity,
            "components": [c.to_dict() for c in self.components],
            "combined_standard_um": self.combined_um,
            "coverage_factor": self.coverage_factor,
            "expanded_um": self.expanded_um,
        }


@dataclass(frozen=True)
class UncertaintyInputs:
    """What the analysis cannot see in the samples. ``None`` resolutions are estimated
    from the data (the smallest step between readings). ``sampling_bound_um``: the
    half-width a of the sampling error on b (skew x speed, latch jitter x speed).
    ``transmission_rel_tolerance``: half-width of the relative uncertainty of the
    configured k_a. ``repeatability_um``/``normalisation_um``: standard uncertainties
    from the history, when the caller has one. ``clock_uncertainty_s``: a bound on the
    error of each sample's time stamp (polled samples; the outlier test's smoothness
    checks allow for it, the backlash does not depend on it)."""

    table_resolution_um: float | None = None
    motor_resolution_um: float | None = None
    sampling_bound_um: float = 0.0
    transmission_rel_tolerance: float = 0.0
    repeatability_um: float = 0.0
    normalisation_um: float = 0.0
    clock_uncertainty_s: float = 0.0
    notes: dict = field(default_factory=dict, compare=False)

    def __post_init__(self) -> None:
        for key in ("table_resolution_um", "motor_resolution_um", "sampling_bound_um",
                    "transmission_rel_tolerance", "repeatability_um", "normalisation_um", "clock_uncertainty_s"):
            v = getattr(self, key)
            if v is not None and not (isinstance(v, (int, float)) and math.isfinite(v) and v >= 0):
                raise InputError(f"{key} (={v!r}) must be a finite number >= 0")


def resolution_component(table_resolution_um: float, motor_resolution_um: float) -> UncertaintyComponent:
    u = math.sqrt((table_resolution_um**2 + motor_resolution_um**2) / 12.0)
    return UncertaintyComponent(
        "resolution", u, f"q_table {table_resolution_um:.3g} µm, q_motor {motor_resolution_um:.3g} µm, rectangular")


def sampling_component(bound_um: float) -> UncertaintyComponent:
    return UncertaintyComponent("sampling", bound_um / math.sqrt(3.0), f"bound ±{bound_um:.3g} µm, rectangular")


def history_components(inputs: UncertaintyInputs) -> tuple[UncertaintyComponent, ...]:
    out = []
    if inputs.repeatability_um > 0:
        out.append(UncertaintyComponent("repeatability", inputs.repeatability_um,
                                        inputs.notes.get("repeatability", "recent cycles at similar temperature")))
    if inputs.normalisation_um > 0:
        out.append(UncertaintyComponent("normalisation", inputs.normalisation_um,
                                        inputs.notes.get("normalisation", "20 °C normalisation: β and thermometer")))
    return tuple(out)


def inputs_of_run(extra: dict) -> UncertaintyInputs:
    """The inputs a stored round-trip run states in its ``extra`` fields: the sampling
    bound (``skew_uncertainty_um``, separate reads) and the time stamps' bound
    (``clock_uncertainty_s``, polled samples)."""
    return UncertaintyInputs(sampling_bound_um=float(extra.get("skew_uncertainty_um") or 0.0),
                             clock_uncertainty_s=float(extra.get("clock_uncertainty_s") or 0.0))
