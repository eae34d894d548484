import json
import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from core.circle import Instrument, analyze, test_from_positions
from core.circle.figures import deviation_um, points_um
from core.errors import InputError
from tests.core.circle.helpers import EXACT, drawn_path, drawn_test


def test_an_offset_circle_gives_its_centre_offset_and_no_circular_deviation():
    f = analyze(drawn_test(centre_um=(7.0, -3.0)))
    assert f.centre_offset_um == pytest.approx((7.0, -3.0), abs=1e-6)
    assert f.circular_deviation_um == pytest.approx(0.0, abs=1e-6)
    assert f.circular_deviation_mz_um == pytest.approx(0.0, abs=1e-6)
    assert f.mean_radius_deviation_um == pytest.approx(0.0, abs=1e-6)
    # about the nominal centre the path reads R + 7 cos θ - 3 sin θ: F = ±√58
    assert f.radial_deviation_max_um == pytest.approx(math.sqrt(58.0), abs=1e-3)
    assert f.radial_deviation_min_um == pytest.approx(-math.sqrt(58.0), abs=1e-3)
    assert f.hysteresis_um == pytest.approx(0.0, abs=1e-6)


def test_an_ellipse_gives_g_twice_its_semi_axis_difference_and_its_f():
    f = analyze(drawn_test(ellipse_um=4.0, ellipse_deg=30.0, centre_um=(2.0, 1.0)))
    assert f.circular_deviation_um == pytest.approx(8.0, abs=1e-4)
    assert f.circular_deviation_mz_um == pytest.approx(8.0, abs=1e-4)
    assert f.centre_offset_um == pytest.approx((2.0, 1.0), abs=1e-6)
    assert f.per_direction["ccw"]["circular_deviation_um"] == pytest.approx(8.0, abs=1e-4)
    # an ellipse is no reversal: no spike rises above its uncertainty
    assert all(abs(s.height_um) <= max(s.height_uncertainty_um, 1e-3) for s in f.spikes)


def test_ellipses_tilted_opposite_ways_give_a_hysteresis_of_twice_their_amplitude():
    e = 3.0
    t = test_from_positions({"ccw": drawn_path(50.0, "ccw", ellipse_um=e, ellipse_deg=45.0),
                             "cw": drawn_path(50.0, "cw", ellipse_um=e, ellipse_deg=-45.0)},
                            radius_mm=50.0, feed_mm_min=1000.0, plane=("x", "y"), instrument=EXACT)
    f = analyze(t)
    # e cos 2(θ - 45°) - e cos 2(θ + 45°) = 2 e sin 2θ
    assert f.hysteresis_um == pytest.approx(2 * e, abs=1e-4)
    assert f.circular_deviation_um == pytest.approx(2 * e, abs=1e-4)  # both paths about one centre


def _bump(height_um, centre_deg, fwhm_deg):
    sigma = math.radians(fwhm_deg) / (2 * math.sqrt(2 * math.log(2)))

    def extra(t):
        d = (t - math.radians(centre_deg) + math.pi) % (2 * math.pi) - math.pi
        return height_um * np.exp(-0.5 * (d / sigma) ** 2)

    return extra


def test_a_drawn_spike_is_found_with_its_height_width_and_axis():
    t = test_from_positions(
        {"ccw": drawn_path(50.0, "ccw", ellipse_um=2.0, ellipse_deg=45.0, extra=_bump(10.0, 93.0, 4.0), n=36000),
         "cw": drawn_path(50.0, "cw", ellipse_um=2.0, ellipse_deg=45.0, n=36000)},
        radius_mm=50.0, feed_mm_min=1000.0, plane=("x", "y"), instrument=EXACT)
    f = analyze(t)
    spike = next(s for s in f.spikes if s.direction == "ccw" and s.quadrant_deg == 90.0)
    assert spike.axis == "y"
    assert spike.height_um == pytest.approx(10.0, abs=max(spike.height_uncertainty_um, 0.05))
    assert spike.width_deg == pytest.approx(4.0, abs=0.05)
    assert spike.peak_deg == pytest.approx(93.0, abs=0.02)
    for s in f.spikes:
        if s is not spike:
            assert abs(s.height_um) <= max(s.height_uncertainty_um, 0.05)
    # the same bump in the ccw pass only is the hysteresis
    assert f.hysteresis_um == pytest.approx(10.0, abs=0.05)


def test_a_one_sided_bump_pulls_the_least_squares_centre_and_the_minimum_zone_does_better():
    f = analyze(drawn_test(extra=_bump(6.0, 200.0, 30.0), n=7200))
    assert f.circular_deviation_mz_um < f.circular_deviation_um - 0.2  # 5.32 against 5.71 µm


def _g_about(test, centre_um):
    dev = np.concatenate([deviation_um(*points_um(p, test.radius_mm * 1e3), np.asarray(centre_um),
                                        test.radius_mm * 1e3) for p in test.passes])
    return float(dev.max() - dev.min())


@settings(max_examples=25, deadline=None)
@given(st.integers(0, 2**32 - 1), st.floats(0.0, 2.0), st.floats(0.0, 5.0), st.integers(2, 7), st.floats(0.0, 4.0))
def test_minimum_zone_g_is_never_above_least_squares_and_no_nearby_centre_does_better(seed, noise, ellipse, lobes,
                                                                                      lobe_um):
    rng = np.random.default_rng(seed)
    n = int(rng.integers(200, 2000))

    def extra(t):
        return lobe_um * np.cos(lobes * t + rng.uniform(0, 6)) + rng.normal(0.0, noise, t.size)

    t = drawn_test(20.0, n=n, ellipse_um=ellipse, ellipse_deg=float(rng.uniform(0, 180)),
                   centre_um=tuple(rng.uniform(-20, 20, 2)), extra=extra)
    f = analyze(t)
    assert f.circular_deviation_mz_um <= f.circular_deviation_um
    g_mz = _g_about(t, f.centre_offset_mz_um)
    assert g_mz == pytest.approx(f.circular_deviation_mz_um, abs=1e-9)
    for _ in range(8):
        nearby = np.asarray(f.centre_offset_mz_um) + rng.normal(0.0, 0.3, 2)
        assert _g_about(t, nearby) >= f.circular_deviation_mz_um - 1e-3


def test_budgets_list_every_component_and_expand_by_two():
    ins = Instrument("ballbar", resolution_um=0.1, accuracy_um=0.5, name="ballbar 100 mm")
    f = analyze(drawn_test(instrument=ins, ellipse_um=2.0, extra=lambda t: 0.2 * np.sin(37 * t)))
    g = f.budgets["circular_deviation"]
    names = {c.name for c in g.components}
    assert {"resolution", "noise", "accuracy", "sampling"} <= names
    assert f.circular_deviation_uncertainty_um == pytest.approx(2 * g.combined_um)
    acc = next(c for c in g.components if c.name == "accuracy")
    assert acc.standard_um == pytest.approx(math.sqrt(2) * 0.5)
    h = next(c for c in f.budgets["hysteresis"].components if c.name == "accuracy")
    assert h.standard_um == 0 and "cancels" in h.note
    # every zero component says why
    for b in f.budgets.values():
        for c in b.components:
            assert c.standard_um > 0 or c.note.startswith("0:")


def test_uncertainty_grows_with_the_noise_of_the_reading():
    quiet = analyze(drawn_test(extra=lambda t: np.random.default_rng(1).normal(0, 0.05, t.size)))
    noisy = analyze(drawn_test(extra=lambda t: np.random.default_rng(1).normal(0, 0.5, t.size)))
    assert noisy.noise_um == pytest.approx(0.5, rel=0.1)
    assert quiet.noise_um == pytest.approx(0.05, rel=0.1)
    assert noisy.circular_deviation_uncertainty_um > 5 * quiet.circular_deviation_uncertainty_um


def test_one_direction_has_no_hysteresis():
    f = analyze(drawn_test(directions=("cw",), ellipse_um=1.0))
    assert f.hysteresis_um is None and f.hysteresis_uncertainty_um is None
    assert [s.direction for s in f.spikes] == ["cw"] * 4


def test_figures_as_json_carry_units_in_their_keys():
    d = analyze(drawn_test(ellipse_um=1.0)).to_dict()
    json.dumps(d)
    for key in d:
        if key not in ("plane", "directions", "spikes", "per_direction", "uncertainty_budget", "coverage_factor",
                       "minimum_zone_note"):
            assert key.endswith(("_um", "_mm", "_mm_min", "_deg")), key
    assert d["uncertainty_budget"]["circular_deviation"]["expanded_um"] == d["circular_deviation_uncertainty_um"]


@pytest.mark.parametrize("w", [0.5, 85.0, float("nan")])
def test_spike_window_out_of_range_is_refused(w):
    with pytest.raises(InputError, match="spike_window_deg"):
        analyze(drawn_test(), spike_window_deg=w)
