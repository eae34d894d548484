"""core.compensation: the grid, the point limit, the zero of e, and its sign convention."""

import numpy as np
import pytest

from core.compensation import QUANTUM_MM, compensation_table
from core.criteria import analyze_round_trip
from core.dataset import AxisSpec
from core.errors import InputError
from tests.core.criteria.synth import round_trip

AXIS = AxisSpec("x", 6.857, 16.0, 10.0, (0.0, 203.0))


@pytest.fixture(scope="module")
def result():
    s = round_trip(start_mm=-5.0, end_mm=208.0, feed_mm_min=3000, rate_hz=250.0,
                   backlash_um=lambda u: 100.0 + 0.1 * u, lead_error_um=lambda u: 0.05 * u, table_noise_um=0.0)
    return analyze_round_trip(s.time_s, s.motor_rev, s.table_mm, AXIS)


def test_grid_spans_the_useful_travel_on_whole_tenths_of_a_micrometre(result):
    t = compensation_table(result, step_mm=7.0)  # 203 mm is no multiple of 7 mm: 29 intervals of 7 mm
    assert t.position_mm[0] == 0.0 and t.position_mm[-1] == pytest.approx(203.0)
    assert t.step_mm == pytest.approx(7.0) and not t.coarsened
    units = t.position_mm / QUANTUM_MM
    assert np.allclose(units, np.rint(units), atol=1e-6)


def test_sign_convention_actual_minus_nominal(result):
    """Feeding +, the table lags the nut by b/2: e+ < e-, and b = e- - e+ (Eq. 5)."""
    t = compensation_table(result, step_mm=5.0)
    assert np.all(t.forward_error_um < t.reverse_error_um)
    assert t.backlash_um == pytest.approx(100.0 + 0.1 * t.position_mm, abs=0.3)
    # e+ = e(u) - b/2 and e- = e(u) + b/2: the lead error rises 0.05 µm/mm, b 0.1 µm/mm
    assert np.polyfit(t.position_mm, t.forward_error_um, 1)[0] == pytest.approx(0.0, abs=0.002)
    assert np.polyfit(t.position_mm, t.reverse_error_um, 1)[0] == pytest.approx(0.1, abs=0.002)


def test_point_limit_coarsens_the_step(result):
    t = compensation_table(result, step_mm=0.5, max_points=50)
    assert t.n_points == 50 and t.coarsened and t.step_mm > 0.5 and t.position_mm[-1] <= 203.0
    # within the limit the step only shrinks as far as ending on the travel's end: 41 x 4.9512 mm
    t = compensation_table(result, step_mm=5.0, max_points=256)
    assert t.n_points == 42 and not t.coarsened and 4.9 < t.step_mm <= 5.0
    assert t.position_mm[-1] == pytest.approx(203.0, abs=0.01)


def test_reference_sets_the_midline_zero_there(result):
    t = compensation_table(result, step_mm=7.0, reference_mm=98.0)
    k = int(np.argmin(np.abs(t.position_mm - 98.0)))
    assert t.position_mm[k] == pytest.approx(98.0)
    assert t.forward_error_um[k] + t.reverse_error_um[k] == pytest.approx(0.0, abs=1e-9)
    with pytest.raises(InputError, match="reference_mm"):
        compensation_table(result, reference_mm=500.0)


@pytest.mark.parametrize("step", [0.0, -1.0, float("nan")])
def test_bad_step_is_named(result, step):
    with pytest.raises(InputError, match="step_mm"):
        compensation_table(result, step_mm=step)
