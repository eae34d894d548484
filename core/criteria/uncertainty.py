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
- ``scale``: the linear scale's own error, which no trace can show: its short-range
  accuracy ±a_s (over the few hundred µm between the two directions' readings of b̄,
  and within one screw lead) or its accuracy class ±a_c per metre over a longer window
  (e_p over the useful travel, v_u, v_300): a = max(a_s, a_c w / 1 m), rectangular:
  a/√3 (Type B). Defaults: a common glass scale, ±5 µm per metre, ±1 µm short-range;
- ``temperature``: the thermometer's tolerance ±(A + B|t|) (IEC 60751; default a Pt100
  of class B, ±(0.30 + 0.005|t|) °C), rectangular, times the thermal expansion β
  (default steel, 11.5e-6 /K) of the length the quantity spans: b̄ itself for b̄, the
  useful travel for e_p (Type B). A uniform expansion only tilts l_a - l_0: the bands
  v_u, v_300, v_2π are taken about the mean travel line, so they keep a zero component
  that says so;
- ``repeatability`` and ``normalisation``: once history exists, the scatter of recent
  cycles at similar temperature and the uncertainty of the 20 °C normalisation
  (β and the thermometer); given by the caller (the service), 0 when absent.

A component that is zero is listed all the same, with a note saying why (encoders
that are not quantised, no noise in the data, latched samples, ...): the budget shows
every source it considered. The scale's and the thermometer's components are always
nonzero unless the caller states an exact instrument (validation on synthetic traces).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

from core.errors import InputError

COVERAGE_FACTOR = 2.0

# IEC 60751 tolerance classes of platinum resistance thermometers: ±(A + B|t|) °C
THERMOMETER_CLASSES = {"AA": (0.10, 0.0017), "A": (0.15, 0.002), "B": (0.30, 0.005), "C": (0.60, 0.01)}
DEFAULT_THERMOMETER_CLASS = "B"
DEFAULT_SCALE_ACCURACY_UM = 1.0  # short-range accuracy of a common glass scale, ± µm
DEFAULT_SCALE_ACCURACY_UM_PER_M = 5.0  # its accuracy class, ± µm per metre of travel
STEEL_EXPANSION_PER_K = 11.5e-6
REFERENCE_TEMPERATURE_C = 20.0


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
class Instruments:
    """What an axis is measured with, for its budget: the linear scale's short-range
    accuracy (± µm) and accuracy class (± µm per metre), the thermometer's IEC 60751
    class, and the axis' thermal expansion coefficient (1/K). The defaults: a common
    glass scale (±1 µm short-range, ±5 µm/m), a Pt100 of class B, steel."""

    scale_accuracy_um: float = DEFAULT_SCALE_ACCURACY_UM
    scale_accuracy_um_per_m: float = DEFAULT_SCALE_ACCURACY_UM_PER_M
    thermometer_class: str = DEFAULT_THERMOMETER_CLASS
    thermal_expansion_per_k: float = STEEL_EXPANSION_PER_K

    def __post_init__(self) -> None:
        for key in ("scale_accuracy_um", "scale_accuracy_um_per_m", "thermal_expansion_per_k"):
            v = getattr(self, key)
            if not (isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v) and v > 0):
                raise InputError(f"{key} (={v!r}) must be a finite number > 0: no instrument is exact")
        if self.scale_accuracy_um > 1000.0 or self.scale_accuracy_um_per_m > 1000.0:
            raise InputError(f"scale_accuracy_um (={self.scale_accuracy_um}) and scale_accuracy_um_per_m "
                             f"(={self.scale_accuracy_um_per_m}) must be at most 1000 µm")
        if self.thermal_expansion_per_k > 1e-4:
            raise InputError(f"thermal_expansion_per_k (={self.thermal_expansion_per_k}) must be at most 1e-4 /K "
                             "(steel: 11.5e-6, cast iron: 10.5e-6)")
        if self.thermometer_class not in THERMOMETER_CLASSES:
            raise InputError(f"thermometer_class (={self.thermometer_class!r}) must be one of "
                             f"{', '.join(THERMOMETER_CLASSES)} (IEC 60751)")

    def inputs(self, **kw) -> "UncertaintyInputs":
        """The budget's inputs with these instruments (``kw``: the other inputs)."""
        return UncertaintyInputs(scale_accuracy_um=self.scale_accuracy_um,
                                 scale_accuracy_um_per_m=self.scale_accuracy_um_per_m,
                                 thermometer_class=self.thermometer_class,
                                 thermal_expansion_per_k=self.thermal_expansion_per_k, **kw)

    def to_dict(self) -> dict:
        return {"scale_accuracy_um": self.scale_accuracy_um, "scale_accuracy_um_per_m": self.scale_accuracy_um_per_m,
                "thermometer_class": self.thermometer_class, "thermal_expansion_per_k": self.thermal_expansion_per_k}


@dataclass(frozen=True)
class UncertaintyInputs:
    """What the analysis cannot see in the samples. ``None`` resolutions are estimated
    from the data (the smallest step between readings). ``sampling_bound_um``: the
    half-width a of the sampling error on b (skew x speed, latch jitter x speed).
    ``transmission_rel_tolerance``: half-width of the relative uncertainty of the
    configured k_a. ``repeatability_um``/``normalisation_um``: standard uncertainties
    from the history, when the caller has one. ``clock_uncertainty_s``: a bound on the
    error of each sample's time stamp (polled samples; the outlier test's smoothness
    checks allow for it, the backlash does not depend on it).

    The instruments: ``scale_accuracy_um`` the linear scale's short-range accuracy
    (± µm), ``scale_accuracy_um_per_m`` its accuracy class (± µm per metre);
    ``thermometer_class`` an IEC 60751 class (``THERMOMETER_CLASSES``),
    ``thermal_expansion_per_k`` β of the axis, ``temperature_c`` the temperature the
    round trip was measured at (None: not measured; the tolerance is taken at 20 °C)."""

    table_resolution_um: float | None = None
    motor_resolution_um: float | None = None
    sampling_bound_um: float = 0.0
    transmission_rel_tolerance: float = 0.0
    repeatability_um: float = 0.0
    normalisation_um: float = 0.0
    clock_uncertainty_s: float = 0.0
    scale_accuracy_um: float = DEFAULT_SCALE_ACCURACY_UM
    scale_accuracy_um_per_m: float = DEFAULT_SCALE_ACCURACY_UM_PER_M
    thermometer_class: str = DEFAULT_THERMOMETER_CLASS
    thermal_expansion_per_k: float = STEEL_EXPANSION_PER_K
    temperature_c: float | None = None
    notes: dict = field(default_factory=dict, compare=False)

    def __post_init__(self) -> None:
        for key in ("table_resolution_um", "motor_resolution_um", "sampling_bound_um",
                    "transmission_rel_tolerance", "repeatability_um", "normalisation_um", "clock_uncertainty_s",
                    "scale_accuracy_um", "scale_accuracy_um_per_m", "thermal_expansion_per_k"):
            v = getattr(self, key)
            if v is not None and not (isinstance(v, (int, float)) and math.isfinite(v) and v >= 0):
                raise InputError(f"{key} (={v!r}) must be a finite number >= 0")
        if self.thermometer_class not in THERMOMETER_CLASSES:
            raise InputError(f"thermometer_class (={self.thermometer_class!r}) must be one of "
                             f"{', '.join(THERMOMETER_CLASSES)} (IEC 60751)")
        t = self.temperature_c
        if t is not None and not (isinstance(t, (int, float)) and math.isfinite(t)):
            raise InputError(f"temperature_c (={t!r}) must be a finite number or None")

    def thermometer_bound_c(self) -> float:
        """Half-width of the thermometer's error at the measured temperature, °C."""
        a, b = THERMOMETER_CLASSES[self.thermometer_class]
        t = REFERENCE_TEMPERATURE_C if self.temperature_c is None else self.temperature_c
        return a + b * abs(t)


def resolution_component(table_resolution_um: float, motor_resolution_um: float) -> UncertaintyComponent:
    u = math.sqrt((table_resolution_um**2 + motor_resolution_um**2) / 12.0)
    note = f"q_table {table_resolution_um:.3g} µm, q_motor {motor_resolution_um:.3g} µm, rectangular"
    if u == 0:
        note = ("0: the readings are not quantised (simulated or interpolated encoders), or the lattice "
                "adds no noise to l_a - l_0")
    return UncertaintyComponent("resolution", u, note)


def sampling_component(bound_um: float) -> UncertaintyComponent:
    if bound_um == 0:
        return UncertaintyComponent("sampling", 0.0, "0: motor and table are latched together (no read skew)")
    return UncertaintyComponent("sampling", bound_um / math.sqrt(3.0), f"bound ±{bound_um:.3g} µm, rectangular")


def scale_component(inputs: UncertaintyInputs, window_mm: float | None) -> UncertaintyComponent:
    """The linear scale's error over ``window_mm`` (None: short range, b̄), rectangular."""
    a_short, a_class = inputs.scale_accuracy_um, inputs.scale_accuracy_um_per_m
    if window_mm is None:
        bound, how = a_short, "short-range accuracy"
    else:
        over = a_class * window_mm / 1000.0
        bound, how = (over, f"class ±{a_class:g} µm/m over {window_mm:g} mm") if over > a_short else (
            a_short, f"short-range accuracy (window {window_mm:g} mm)")
    if bound == 0:
        return UncertaintyComponent("scale", 0.0, "0: the scale is stated to be exact")
    return UncertaintyComponent("scale", bound / math.sqrt(3.0), f"linear scale {how}: ±{bound:.3g} µm, rectangular")


def temperature_component(inputs: UncertaintyInputs, length_mm: float, what: str) -> UncertaintyComponent:
    """The thermometer's tolerance times the expansion of ``length_mm`` (``what`` spans it)."""
    bound_c = inputs.thermometer_bound_c()
    u = bound_c / math.sqrt(3.0) * inputs.thermal_expansion_per_k * abs(length_mm) * 1e3
    at = "20 °C (temperature not measured)" if inputs.temperature_c is None else f"{inputs.temperature_c:.1f} °C"
    note = (f"Pt100 class {inputs.thermometer_class} ±{bound_c:.2f} °C at {at}, rectangular, "
            f"× β {inputs.thermal_expansion_per_k:.3g}/K over {what} {abs(length_mm):.4g} mm")
    if u == 0:
        note = "0: " + ("the expansion coefficient is stated as 0" if inputs.thermal_expansion_per_k == 0
                        else f"{what} spans no length")
    return UncertaintyComponent("temperature", u, note)


BAND_TEMPERATURE = UncertaintyComponent(
    "temperature", 0.0, "0: a uniform expansion only tilts l_a - l_0; the band is taken about the mean travel line")


def history_components(inputs: UncertaintyInputs) -> tuple[UncertaintyComponent, ...]:
    out = []
    if inputs.repeatability_um > 0:
        out.append(UncertaintyComponent("repeatability", inputs.repeatability_um,
                                        inputs.notes.get("repeatability", "recent cycles at similar temperature")))
    if inputs.normalisation_um > 0:
        out.append(UncertaintyComponent("normalisation", inputs.normalisation_um,
                                        inputs.notes.get("normalisation", "20 °C normalisation: β and thermometer")))
    return tuple(out)


def inputs_of_run(extra: dict, instruments: Instruments | None = None,
                  temperature_c: float | None = None) -> UncertaintyInputs:
    """The inputs a stored round-trip run states in its ``extra`` fields: the sampling
    bound (``skew_uncertainty_um``, separate reads) and the time stamps' bound
    (``clock_uncertainty_s``, polled samples); with ``instruments`` (None: those the run
    states, ``instruments``, else :class:`Instruments`' defaults) and the run's measured
    ``temperature_c`` (None: not measured)."""
    t = temperature_c if temperature_c is not None and math.isfinite(temperature_c) else None
    if instruments is None:
        stated = extra.get("instruments")
        instruments = Instruments(**stated) if isinstance(stated, dict) else Instruments()
    return instruments.inputs(
        sampling_bound_um=float(extra.get("skew_uncertainty_um") or 0.0),
        clock_uncertainty_s=float(extra.get("clock_uncertainty_s") or 0.0), temperature_c=t)


def inputs_of_spec(spec, instruments: Instruments | None = None) -> UncertaintyInputs:
    """:func:`inputs_of_run` of a stored run's ``RunSpec``: its ``extra`` fields and its
    temperature (unless the run says it was not measured, ``temperature_measured``)."""
    return inputs_of_run(spec.extra, instruments, float(spec.temperature_c) if spec.temperature_measured else None)
