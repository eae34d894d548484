"""GUM budgets of a round trip: components, keys, and coverage on seeded round trips."""

import math

import numpy as np
import pytest

from core.criteria import analyze_round_trip
from core.criteria.uncertainty import UncertaintyBudget, UncertaintyComponent, UncertaintyInputs
from core.dataset import AxisSpec
from core.errors import InputError
from tests.core.criteria.synth import round_trip, true_criteria

AXIS = AxisSpec("y", 6.857, 16.0, 10.0, (0.0, 100.0))


def backlash(u):
    return 120.0 + 12.0 * np.sin(2 * np.pi * u / 450.0) + 0.01 * u


def lead_error(u):
    return 4.0 * np.sin(2 * np.pi * u / 16.0 + 0.3) + 6.0 * np.sin(2 * np.pi * u / 300.0 + 1.0) - 0.02 * u


TRUE_B, _, _ = true_criteria(0.0, 100.0, backlash, lead_error)
# the synthetic traces' scale and temperature are exact: the coverage test judges the
# components the data show (the instruments' own are stated, not simulated)
EXACT_INSTRUMENTS = UncertaintyInputs(scale_accuracy_um=0.0, scale_accuracy_um_per_m=0.0, thermal_expansion_per_k=0.0)


def _trip(seed, **kw):
    kw = {"start_mm": -3.0, "end_mm": 103.0, "feed_mm_min": 2000, "rate_hz": 1000.0, "backlash_um": backlash,
          "lead_error_um": lead_error, "table_noise_um": 0.3, "motor_noise_um": 0.3,
          "rng": np.random.default_rng(seed), **kw}
    return round_trip(**kw)


def test_expanded_uncertainty_covers_the_true_error_of_b_mean_and_is_not_inflated():
    errors, expanded = [], []
    for seed in range(100):
        s = _trip(seed)
        r = analyze_round_trip(s.time_s, s.motor_rev, s.table_mm, AXIS, uncertainty=EXACT_INSTRUMENTS)
        errors.append(r.backlash.mean_um - TRUE_B)
        expanded.append(r.backlash_mean_uncertainty_um)
    errors, expanded = np.array(errors), np.array(expanded)
    assert np.mean(np.abs(errors) <= expanded) >= 0.90
    assert expanded.mean() <= 4.0 * errors.std()


def test_budget_keys_in_the_result_dict():
    s = _trip(0)
    d = analyze_round_trip(s.time_s, s.motor_rev, s.table_mm, AXIS).to_dict()
    assert d["backlash_mean_uncertainty_um"] > 0
    for key in ("e_p", "v_u", "v_300", "v_2pi"):
        assert d[f"{key}_uncertainty_um"] == d["strokes"]["positive"][f"{key}_uncertainty_um"] > 0
        assert d["strokes"]["negative"][f"{key}_uncertainty_um"] > 0
    b = d["uncertainty_budget"]["backlash_mean"]
    assert b["coverage_factor"] == 2.0
    assert b["expanded_um"] == pytest.approx(2.0 * b["combined_standard_um"])
    assert b["combined_standard_um"] == pytest.approx(math.sqrt(sum(c["standard_um"] ** 2 for c in b["components"])))
    assert {c["name"] for c in b["components"]} >= {"resolution", "noise", "sampling", "reduction", "scale",
                                                    "temperature"}
    for budget in d["uncertainty_budget"].values():
        for c in budget["components"]:
            assert c["standard_um"] > 0 or c["note"].startswith("0: "), (budget["quantity"], c)


def test_the_scale_and_the_thermometer_are_in_every_budget_even_with_perfect_encoders():
    s = _trip(3, table_noise_um=0.0, motor_noise_um=0.0)
    r = analyze_round_trip(s.time_s, s.motor_rev, s.table_mm, AXIS)
    comp = {c.name: c for c in r.budgets["backlash_mean"].components}
    # a common glass scale: ±1 µm short-range, rectangular
    assert comp["scale"].standard_um == pytest.approx(1.0 / math.sqrt(3))
    assert "short-range" in comp["scale"].note
    # a Pt100 of class B at 20 °C (±0.40 °C, not measured) over b̄ (~120 µm) of steel: tiny, not zero
    assert comp["temperature"].standard_um == pytest.approx(
        0.40 / math.sqrt(3) * 11.5e-6 * r.backlash.mean_um, rel=1e-9)
    assert comp["temperature"].standard_um > 0 and "class B" in comp["temperature"].note
    # the data alone would claim next to nothing; the instruments keep U(b̄) honest
    assert comp["noise"].standard_um < 1e-3
    assert r.backlash_mean_uncertainty_um >= 2 / math.sqrt(3)
    # e_p over the useful travel: the scale's class (±5 µm/m) and the thermometer times β L
    length_mm = r.useful_travel_mm[1] - r.useful_travel_mm[0]
    ep = {c.name: c for c in r.budgets["positive.e_p"].components}
    assert ep["scale"].standard_um == pytest.approx(max(1.0, 5.0 * length_mm / 1000) / math.sqrt(3))
    assert ep["temperature"].standard_um == pytest.approx(0.40 / math.sqrt(3) * 11.5e-6 * length_mm * 1e3)
    # within 300 mm of a 100 mm travel: the short-range accuracy; a band keeps a zero, explained, temperature term
    v = {c.name: c for c in r.budgets["positive.v_300"].components}
    assert v["scale"].standard_um == pytest.approx(1.0 / math.sqrt(3))
    assert v["temperature"].standard_um == 0 and "mean travel line" in v["temperature"].note


def test_the_instruments_are_configurable_and_a_measured_temperature_widens_the_thermometer():
    s = _trip(4)
    inputs = UncertaintyInputs(scale_accuracy_um=2.0, scale_accuracy_um_per_m=3.0, thermometer_class="A",
                               temperature_c=30.0)
    r = analyze_round_trip(s.time_s, s.motor_rev, s.table_mm, AXIS, uncertainty=inputs)
    comp = {c.name: c for c in r.budgets["backlash_mean"].components}
    assert comp["scale"].standard_um == pytest.approx(2.0 / math.sqrt(3))
    bound = 0.15 + 0.002 * 30.0
    assert comp["temperature"].standard_um == pytest.approx(bound / math.sqrt(3) * 11.5e-6 * r.backlash.mean_um)
    assert "30.0 °C" in comp["temperature"].note
    assert UncertaintyInputs(temperature_c=-10.0).thermometer_bound_c() == pytest.approx(0.35)
    with pytest.raises(InputError, match="thermometer_class"):
        UncertaintyInputs(thermometer_class="D")
    with pytest.raises(InputError, match="scale_accuracy_um"):
        UncertaintyInputs(scale_accuracy_um=-1.0)


def test_sampling_skew_resolution_transmission_and_history_enter_the_budget():
    s = _trip(1)
    plain = analyze_round_trip(s.time_s, s.motor_rev, s.table_mm, AXIS)
    inputs = UncertaintyInputs(table_resolution_um=1.0, motor_resolution_um=0.5, sampling_bound_um=3.0,
                               transmission_rel_tolerance=1e-5, repeatability_um=0.4, normalisation_um=0.3)
    r = analyze_round_trip(s.time_s, s.motor_rev, s.table_mm, AXIS, uncertainty=inputs)
    comp = {c.name: c.standard_um for c in r.budgets["backlash_mean"].components}
    assert comp["sampling"] == pytest.approx(3.0 / math.sqrt(3))
    assert comp["resolution"] == pytest.approx(math.sqrt((1.0 + 0.25) / 12))
    assert comp["repeatability"] == 0.4 and comp["normalisation"] == 0.3
    assert r.backlash_mean_uncertainty_um > plain.backlash_mean_uncertainty_um
    ep = {c.name: c.standard_um for c in r.budgets["positive.e_p"].components}
    assert ep["transmission"] == pytest.approx(100.0 * 1e3 * 1e-5 / math.sqrt(3))
    # the result is unchanged: only its uncertainty
    assert r.backlash.mean_um == plain.backlash.mean_um


def test_resolution_is_estimated_from_quantised_readings():
    s = _trip(2, table_noise_um=0.0, motor_noise_um=0.0)
    q = 0.5e-3  # 0.5 µm table scale
    table = np.round(s.table_mm / q) * q
    r = analyze_round_trip(s.time_s, s.motor_rev, table, AXIS)
    res = next(c for c in r.budgets["backlash_mean"].components if c.name == "resolution")
    assert "q_table 0.5 µm" in res.note


def test_budget_arithmetic_and_input_validation():
    b = UncertaintyBudget("x", (UncertaintyComponent("a", 3.0), UncertaintyComponent("b", 4.0)))
    assert (b.combined_um, b.expanded_um) == (5.0, 10.0)
    with pytest.raises(InputError, match="sampling_bound_um"):
        UncertaintyInputs(sampling_bound_um=-1.0)
