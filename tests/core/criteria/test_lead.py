import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from core.criteria import criterion_label, lead_criteria, max_window_band
from core.errors import InputError


@settings(max_examples=100, deadline=None)
@given(arrays(float, st.integers(1, 200), elements=st.floats(-1e3, 1e3)), st.integers(1, 250))
def test_window_band_equals_brute_force(values, w):
    n = values.size
    w_eff = min(w, n)
    brute = max(np.ptp(values[i : i + w_eff]) for i in range(n - w_eff + 1))
    assert max_window_band(values, w) == pytest.approx(brute)


def test_pure_slope_gives_e_p_and_no_variation():
    x = np.linspace(0.0, 1000.0, 4001)
    dev_mm = -18.29e-6 * x  # -18.29 µm per 1000 mm, as on 2013-07-13
    c = lead_criteria(x, dev_mm, direction="positive", screw_lead_mm=16.0)
    assert c.e_p_um_per_1000mm == pytest.approx(-18.29, abs=1e-6)
    assert c.e_p_um == pytest.approx(-18.29, abs=1e-6)
    assert c.v_u_um == pytest.approx(0.0, abs=1e-9)


def test_sinusoid_at_the_lead_sets_every_band():
    x = np.linspace(0.0, 320.0, 3201)
    dev_mm = 5e-3 * np.cos(2 * np.pi * x / 16.0)  # whole periods of a cosine: l_m has no slope
    c = lead_criteria(x, dev_mm, direction="negative", screw_lead_mm=16.0)
    assert c.v_u_um == pytest.approx(10.0, abs=0.01)
    assert c.v_300_um == pytest.approx(10.0, abs=0.01)
    assert c.v_2pi_um == pytest.approx(10.0, abs=0.01)


def test_short_travel_uses_whole_travel_for_v300():
    x = np.linspace(0.0, 100.0, 401)
    dev_mm = 3e-3 * np.sin(2 * np.pi * x / 200.0)
    c = lead_criteria(x, dev_mm, direction="positive", screw_lead_mm=16.0)
    assert c.v_300_um == pytest.approx(c.v_u_um)
    assert c.v_2pi_um < c.v_u_um


def test_rejects_non_uniform_grid():
    with pytest.raises(InputError, match="uniform"):
        lead_criteria(np.array([0.0, 1.0, 3.0]), np.zeros(3), direction="positive", screw_lead_mm=16.0)


def test_criterion_labels_are_iso_3408_3s_names_and_refuse_other_keys():
    assert criterion_label("v_300_um") == "travel variation within 300 mm v_300"
    assert criterion_label("v_2pi") == "travel variation within one revolution (2π rad) v_2π"
    with pytest.raises(KeyError, match="'b_um' is not a lead criterion"):
        criterion_label("b_um")
