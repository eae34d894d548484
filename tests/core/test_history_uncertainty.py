"""The history's components of b̄'s budget: repeatability and the 20 °C normalisation."""

import math

import numpy as np
import pytest

from core.criteria import analyze_round_trip
from core.criteria.roundtrip import with_history_uncertainty
from core.history import TemperatureModel, history_uncertainty
from core.sim import AxisModel, round_trip, simulate


def test_repeatability_is_the_scatter_of_recent_cycles_moved_to_this_temperature():
    rng = np.random.default_rng(0)
    t = rng.uniform(21.0, 23.0, 20)
    b = 200.0 + 2.0 * (t - 20.0) + rng.normal(0, 0.5, 20)
    model = TemperatureModel().fit(t, b)
    assert model.beta_uncertainty_um_per_k_ > 0
    comps = history_uncertainty(22.0, t, b, beta_um_per_k=model.beta_um_per_k_,
                                beta_uncertainty_um_per_k=model.beta_uncertainty_um_per_k_)
    rep, note = comps["repeatability"]
    assert rep == pytest.approx(0.5, rel=0.35) and "20 cycles" in note
    # without β the temperature spread inflates it
    raw = history_uncertainty(22.0, t, b)["repeatability"][0]
    assert raw > rep
    norm = comps["normalisation"][0]
    expect = math.hypot(2.0 * model.beta_uncertainty_um_per_k_, model.beta_um_per_k_ * 0.25)
    assert norm == pytest.approx(expect)
    assert history_uncertainty(22.0, t[:3], b[:3]) == {}  # too few cycles, no β: nothing


def test_the_components_enter_the_stored_budgets():
    ax = AxisModel(backlash_um=50.0)
    tr = simulate({"y": ax}, round_trip(0, 60, 3000), rate_hz=500)
    res = analyze_round_trip(tr.time_s, tr.motor_rev["y"], tr.table_mm["y"], ax.to_axis_spec((5, 55)))
    u0 = res.backlash_mean_uncertainty_um
    out = with_history_uncertainty(res, {"repeatability": (0.8, "s of 10"), "normalisation": (0.6, "β")})
    assert out.backlash_mean_uncertainty_um == pytest.approx(2 * math.hypot(u0 / 2, 0.8))
    b20 = out.budgets["backlash_mean_20c"]
    assert b20.expanded_um == pytest.approx(2 * math.hypot(u0 / 2, 0.8, 0.6))
    d = out.to_dict()
    assert d["backlash_mean_20c_uncertainty_um"] == b20.expanded_um
    names = [c["name"] for c in d["uncertainty_budget"]["backlash_mean"]["components"]]
    assert "repeatability" in names and "normalisation" not in names
    assert with_history_uncertainty(res, {}) is res
