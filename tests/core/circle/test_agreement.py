import math

import pytest

from core.circle import analyze, compare_with_backlash
from core.circle.agreement import EQ8_MODEL_REL, predicted_tbe_um
from core.errors import InputError, ModelDomainError
from core.tbe import MachiningTask, tbe_circle_um
from tests.core.circle.helpers import drawn_test


def test_prediction_is_eq8_with_the_backlash_gain_and_model_uncertainty_combined():
    tbe, u = predicted_tbe_um(100.0, 4.0, radius_mm=50.0, feed_mm_min=2000.0, gain_per_s=10.0,
                              gain_rel_uncertainty=0.02)
    assert tbe == pytest.approx(float(tbe_circle_um(100.0, 50.0, 2000.0, 10.0)))
    task = MachiningTask("t", profile="circle", radius_mm=50.0, feed_mm_min=2000.0, gain_per_s=10.0, tolerance_um=1)
    u_b = task.tbe_uncertainty_um(100.0, 4.0)
    u_k = 2 * max(abs(float(tbe_circle_um(100.0, 50.0, 2000.0, 10.0 * (1 + s * 0.02))) - tbe)
                  for s in (1, -1)) / math.sqrt(3)
    u_model = 2 * EQ8_MODEL_REL * tbe / math.sqrt(3)
    assert u == pytest.approx(math.sqrt(u_b**2 + u_k**2 + u_model**2))
    assert u > u_b > 0 and u_k > 0


def test_a_test_without_spikes_agrees_with_zero_backlash_and_not_with_a_large_one():
    f = analyze(drawn_test(ellipse_um=2.0))
    zero = compare_with_backlash(f, axis="x", backlash_um=0.0, backlash_uncertainty_um=0.0, gain_per_s=10.0)
    assert zero.predicted_um == 0.0 and zero.verdict == "agree"
    big = compare_with_backlash(f, axis="y", backlash_um=50.0, backlash_uncertainty_um=1.0, gain_per_s=10.0)
    assert big.verdict == "smaller" and big.normalised_error < -1
    assert "compensates" in big.meaning
    d = big.to_dict()
    assert d["spikes"] == ["ccw@90°", "ccw@270°", "cw@90°", "cw@270°"]
    assert d["normalised_error"] == big.normalised_error and d["axis"] == "y"


def test_bad_requests_are_refused():
    f = analyze(drawn_test())
    with pytest.raises(InputError, match="does not reverse"):
        compare_with_backlash(f, axis="z", backlash_um=10.0, backlash_uncertainty_um=1.0, gain_per_s=10.0)
    with pytest.raises(InputError, match="backlash_um"):
        compare_with_backlash(f, axis="x", backlash_um=-1.0, backlash_uncertainty_um=1.0, gain_per_s=10.0)
    with pytest.raises(InputError, match="gain_per_s"):
        compare_with_backlash(f, axis="x", backlash_um=10.0, backlash_uncertainty_um=1.0, gain_per_s=0.0)
    fast = analyze(drawn_test(5.0, feed_mm_min=5000.0))
    with pytest.raises(ModelDomainError, match="Eq. 8 cannot predict"):
        # 5 mm of backlash on a 5 mm circle at 5000 mm/min delays the axis beyond a quarter turn (edge 4.17 mm)
        compare_with_backlash(fast, axis="x", backlash_um=5000.0, backlash_uncertainty_um=1.0, gain_per_s=10.0)
