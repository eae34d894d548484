"""Circles the twin traces (core.sim) against the figures' analytical values."""

import math

import numpy as np
import pytest

from core.circle import analyze, compare_with_backlash
from core.circle.simulate import simulated_test
from core.errors import InputError
from core.sim import Friction, ServoDynamics
from core.tbe import tbe_circle_um

R_MM, FEED_MM_MIN, K_PER_S = 50.0, 2000.0, 10.0


def _p_loop_path(gain_1, gain_2, sense, n=400_001):
    """The steady state of two P loops on R cos ωt, ±R sin ωt: each axis follows with
    amplitude cos φ_i and lag φ_i = arctan(ω/K_i). Returns (angle_deg sorted, radial_um)."""
    w = FEED_MM_MIN / 60.0 / R_MM
    p1, p2 = math.atan(w / gain_1), math.atan(w / gain_2)
    u = np.linspace(0.0, 2 * np.pi, n)
    x = R_MM * math.cos(p1) * np.cos(u - p1)
    y = sense * R_MM * math.cos(p2) * np.sin(u - p2)
    th = np.degrees(np.arctan2(y, x)) % 360.0
    o = np.argsort(th)
    return th[o], (np.hypot(x, y)[o] - R_MM) * 1e3


@pytest.fixture(scope="module")
def mismatch():
    m = 0.01
    return m, analyze(simulated_test(radius_mm=R_MM, feed_mm_min=FEED_MM_MIN, gain_per_s=K_PER_S, gain_mismatch=m))


def test_unequal_gains_give_the_analytical_g_h_and_mean_radius(mismatch):
    m, f = mismatch
    k2 = K_PER_S * (1 + m)
    th_ccw, r_ccw = _p_loop_path(K_PER_S, k2, 1.0)
    th_cw, r_cw = _p_loop_path(K_PER_S, k2, -1.0)
    g = max(r_ccw.max(), r_cw.max()) - min(r_ccw.min(), r_cw.min())
    h = float(np.max(np.abs(r_ccw - np.interp(th_ccw, th_cw, r_cw, period=360.0))))
    assert abs(f.circular_deviation_um - g) <= f.circular_deviation_uncertainty_um + 1e-4
    assert abs(f.circular_deviation_mz_um - g) <= f.circular_deviation_uncertainty_um + 1e-4
    assert abs(f.hysteresis_um - h) <= f.hysteresis_uncertainty_um + 1e-4
    # to first order: H = R ā |φ1 - φ2| and G = R √((a1 - a2)² + (ā (φ1 - φ2))²)
    w = FEED_MM_MIN / 60.0 / R_MM
    p1, p2 = math.atan(w / K_PER_S), math.atan(w / k2)
    a1, a2 = math.cos(p1), math.cos(p2)
    a_mean = (a1 + a2) / 2
    assert f.hysteresis_um == pytest.approx(R_MM * 1e3 * a_mean * abs(p1 - p2), rel=1e-3)
    assert f.circular_deviation_um == pytest.approx(R_MM * 1e3 * math.hypot(a1 - a2, a_mean * (p1 - p2)), rel=1e-3)
    assert f.mean_radius_deviation_um == pytest.approx(R_MM * 1e3 * (a_mean - 1), abs=0.01)
    assert f.hysteresis_um > 30.0  # a 1 % gain mismatch at this feed is tens of µm


def test_unequal_gains_are_no_reversal_spike(mismatch):
    _, f = mismatch
    assert all(abs(s.height_um) <= max(s.height_uncertainty_um, 0.01) for s in f.spikes)


@pytest.fixture(scope="module")
def backlash():
    t = simulated_test(radius_mm=R_MM, feed_mm_min=FEED_MM_MIN, gain_per_s=K_PER_S, backlash_um=(100.0, 60.0),
                       noise_um=0.1, resolution_um=0.05, seed=3)
    return t, analyze(t)


@pytest.mark.parametrize("axis, b_um", [("x", 100.0), ("y", 60.0)])
def test_backlash_spikes_are_eq8_within_their_uncertainty(backlash, axis, b_um):
    _, f = backlash
    eq8 = float(tbe_circle_um(b_um, R_MM, FEED_MM_MIN, K_PER_S))
    spikes = f.spikes_of(axis)
    assert len(spikes) == 4  # two reversals, two directions
    for s in spikes:
        assert abs(s.height_um - eq8) <= s.height_uncertainty_um + 0.002 * eq8  # Eq. 8's own accuracy
        assert 0.5 < s.width_deg < 10.0
    a = compare_with_backlash(f, axis=axis, backlash_um=b_um, backlash_uncertainty_um=1.0, gain_per_s=K_PER_S)
    assert a.verdict == "agree" and a.agree and abs(a.normalised_error) <= 1.0


def test_hysteresis_and_g_of_a_backlash_circle_are_its_largest_spike(backlash):
    _, f = backlash
    eq8 = float(tbe_circle_um(100.0, R_MM, FEED_MM_MIN, K_PER_S))
    # ccw reverses x at 0° and runs its spike where cw runs undisturbed: H is the spike
    assert abs(f.hysteresis_um - eq8) <= f.hysteresis_uncertainty_um + 0.002 * eq8
    assert abs(f.circular_deviation_um - eq8) <= f.circular_deviation_uncertainty_um + 0.002 * eq8
    assert f.circular_deviation_mz_um <= f.circular_deviation_um
    assert f.noise_um == pytest.approx(0.1, rel=0.15)


def test_a_backlash_a_third_off_disagrees_and_says_which_way(backlash):
    _, f = backlash
    low = compare_with_backlash(f, axis="x", backlash_um=60.0, backlash_uncertainty_um=1.0, gain_per_s=K_PER_S)
    assert low.verdict == "larger" and low.normalised_error > 1 and "friction" in low.meaning
    high = compare_with_backlash(f, axis="x", backlash_um=140.0, backlash_uncertainty_um=1.0, gain_per_s=K_PER_S)
    assert high.verdict == "smaller" and high.normalised_error < -1 and "less play" in high.meaning


@pytest.fixture(scope="module")
def friction():
    fr = Friction(coulomb_n=300.0)
    return fr, analyze(simulated_test(radius_mm=R_MM, feed_mm_min=FEED_MM_MIN, gain_per_s=K_PER_S, friction=fr))


def test_coulomb_friction_without_backlash_spikes_and_eq8_says_larger(friction):
    fr, f = friction
    # the chain (200 N/µm by default) winds up by 2 F_c / k at a reversal: an elastic lost
    # motion that acts like a backlash of that width (the chain's dynamics add a little)
    wind_up_um = 2 * fr.coulomb_n / 200.0
    like_backlash = float(tbe_circle_um(wind_up_um, R_MM, FEED_MM_MIN, K_PER_S))
    for s in f.spikes:
        assert s.height_um > 10 * s.height_uncertainty_um
        assert like_backlash <= s.height_um <= 1.2 * like_backlash
    a = compare_with_backlash(f, axis="x", backlash_um=0.0, backlash_uncertainty_um=0.5, gain_per_s=K_PER_S)
    assert a.predicted_um == 0.0
    assert a.verdict == "larger" and not a.agree
    assert "gap diagnosis" in a.meaning


def test_simulated_test_refuses_bad_settings():
    with pytest.raises(InputError, match="gain_mismatch"):
        simulated_test(radius_mm=10, feed_mm_min=500, gain_per_s=10, gain_mismatch=2.0)
    with pytest.raises(InputError, match="directions"):
        simulated_test(radius_mm=10, feed_mm_min=500, gain_per_s=10, directions=("ccw", "ccw"))
    with pytest.raises(InputError, match="backlash_um"):
        simulated_test(radius_mm=10, feed_mm_min=500, gain_per_s=10, backlash_um=(1.0, 2.0, 3.0))


@pytest.mark.parametrize("coulomb_n, verdict", [(None, "agree"), (1500.0, "larger")])
def test_backlash_with_unequal_gains_agrees_and_friction_on_top_makes_the_spikes_larger(coulomb_n, verdict):
    k2 = K_PER_S * 1.01
    f = analyze(simulated_test(radius_mm=R_MM, feed_mm_min=FEED_MM_MIN, gain_per_s=K_PER_S, gain_mismatch=0.01,
                               backlash_um=(100.0, 60.0), noise_um=0.1, seed=2,
                               friction=None if coulomb_n is None else Friction(coulomb_n=coulomb_n)))
    for axis, b_um, k in (("x", 100.0, K_PER_S), ("y", 60.0, k2)):
        a = compare_with_backlash(f, axis=axis, backlash_um=b_um, backlash_uncertainty_um=1.0, gain_per_s=k)
        assert a.verdict == verdict, a.sentence()


def test_the_loop_check_tells_a_proportional_loop_from_a_feed_forward_one(backlash):
    """Away from the reversals a P loop traces R cos φ (R (1 - cos φ) = 4.4 µm inside R at
    R 50 mm, 2000 mm/min, K 10/s): the check agrees. With the velocity fed forward the
    axes trace R itself, while the spikes above that path stay Eq. 8's: the check says
    "larger" and that the drive feeds forward."""
    _, f = backlash
    lag_um = R_MM * (1 - math.cos(math.atan(FEED_MM_MIN / 60.0 / R_MM / K_PER_S))) * 1e3
    p_loop = compare_with_backlash(f, axis="x", backlash_um=100.0, backlash_uncertainty_um=1.0, gain_per_s=K_PER_S)
    assert p_loop.loop.verdict == "agree", p_loop.sentence()
    assert p_loop.loop.predicted_um == pytest.approx(-lag_um, rel=1e-9)
    assert p_loop.loop.measured_um == pytest.approx(-lag_um, abs=p_loop.loop.measured_uncertainty_um + 0.05)
    ff = analyze(simulated_test(radius_mm=R_MM, feed_mm_min=FEED_MM_MIN, gain_per_s=K_PER_S, backlash_um=(100.0, 60.0),
                                servo_dynamics=ServoDynamics(velocity_lag_s=0.0, feedforward=1.0), noise_um=0.1))
    a = compare_with_backlash(ff, axis="x", backlash_um=100.0, backlash_uncertainty_um=1.0, gain_per_s=K_PER_S)
    assert abs(ff.undisturbed_radius_deviation_um) < 0.2 * lag_um  # the full radius
    assert a.loop.verdict == "larger" and a.loop.normalised_error > 3.0, a.sentence()
    assert "feeds the commanded velocity forward" in a.sentence()
    assert a.to_dict()["loop"]["verdict"] == "larger"
