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


def _trip(seed, **kw):
    kw = {"start_mm": -3.0, "end_mm": 103.0, "feed_mm_min": 2000, "rate_hz": 1000.0, "backlash_um": backlash,
          "lead_error_um": lead_error, "table_noise_um": 0.3, "motor_noise_um": 0.3,
          "rng": np.random.default_rng(seed), **kw}
    return round_trip(**kw)


def test_expanded_uncertainty_covers_the_true_error_of_b_mean_and_is_not_inflated():
    errors, expanded = [], []
    for seed in range(100):
        s = _trip(seed)
        r = analyze_round_trip(s.time_s, s.motor_rev, s.table_mm, AXIS)
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
    assert {c["name"] for c in b["components"]} >= {"resolution", "noise", "sampling", "reduction"}


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
