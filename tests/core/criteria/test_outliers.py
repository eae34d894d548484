"""Glitches and bursts on either encoder: dropped, counted, refused past a fraction."""

import numpy as np
import pytest

from core.criteria import analyze_round_trip
from core.criteria.outliers import OutlierSettings, encoder_outliers, hampel_mask, noise_sigma_mm
from core.criteria.roundtrip import RoundTripSettings
from core.criteria.uncertainty import UncertaintyInputs
from core.dataset import AxisSpec
from core.errors import InputError, OutlierError, TraceError
from tests.core.criteria.synth import round_trip, true_criteria

AXIS = AxisSpec("y", 6.857, 16.0, 10.0, (0.0, 300.0))


def backlash(u):
    return 6.0 + 0.0 * u


def lead_error(u):
    return 3.0 * np.sin(2 * np.pi * u / 16.0)


TRUE_B, TRUE_POS, TRUE_NEG = true_criteria(0.0, 300.0, backlash, lead_error)


def _trip(**kw):
    kw = {"start_mm": -5.0, "end_mm": 305.0, "feed_mm_min": 2000, "backlash_um": backlash,
          "lead_error_um": lead_error, "motor_noise_um": 0.2, "table_noise_um": 0.2,
          "rng": np.random.default_rng(3), **kw}
    return round_trip(**kw)


@pytest.mark.parametrize("encoder", ["motor", "table"])
@pytest.mark.parametrize("size_mm", [5.0, -5.0, 0.05])
def test_one_glitch_is_dropped_and_counted(encoder, size_mm):
    # one 5 mm glitch of the motor encoder gave v_2π = 213 µm instead of 6 µm
    s = _trip()
    i = s.time_s.size // 3  # mid-stroke
    if encoder == "motor":
        s.motor_rev[i] += size_mm / AXIS.transmission_mm_per_rev
    else:
        s.table_mm[i] += size_mm
    r = analyze_round_trip(s.time_s, s.motor_rev, s.table_mm, AXIS)
    assert r.outliers_removed == 1
    assert r.to_dict()["outliers_removed"] == 1
    for name, truth in (("positive", TRUE_POS), ("negative", TRUE_NEG)):
        assert r.strokes[name].v_2pi_um == pytest.approx(truth.v_2pi_um, abs=1.0)
    assert r.backlash.mean_um == pytest.approx(TRUE_B, abs=0.5)


def test_a_burst_of_three_samples_is_dropped():
    s = _trip()
    i = s.time_s.size // 3
    s.table_mm[i : i + 3] += 0.2
    r = analyze_round_trip(s.time_s, s.motor_rev, s.table_mm, AXIS)
    assert r.outliers_removed == 3
    assert r.strokes["positive"].v_2pi_um == pytest.approx(TRUE_POS.v_2pi_um, abs=1.0)


def test_a_clean_trace_loses_no_sample():
    r = analyze_round_trip(*vars(_trip()).values(), AXIS)
    assert r.outliers_removed == 0


def test_too_many_glitches_are_a_typed_error_and_the_fraction_is_configurable():
    s = _trip()
    rng = np.random.default_rng(0)
    at = rng.choice(np.arange(100, s.time_s.size - 100), size=s.time_s.size // 50, replace=False)  # 2 %
    s.table_mm[at] += 1.0
    with pytest.raises(OutlierError, match=r"samples of the round trip are outliers \(2\.\d+ % > max_fraction 1 %\)"):
        analyze_round_trip(s.time_s, s.motor_rev, s.table_mm, AXIS)
    assert issubclass(OutlierError, TraceError)
    lenient = RoundTripSettings(outliers=OutlierSettings(max_fraction=0.05))
    r = analyze_round_trip(s.time_s, s.motor_rev, s.table_mm, AXIS, settings=lenient)
    assert r.outliers_removed >= at.size * 0.95
    assert r.strokes["positive"].v_2pi_um == pytest.approx(TRUE_POS.v_2pi_um, abs=1.0)


def test_hampel_flags_exactly_the_glitch_on_a_ramp_and_not_the_reversal():
    t = np.arange(2000) * 1e-3
    x = np.where(t < 1.0, 100.0 * t, 200.0 - 100.0 * t)  # a V at 100 mm/s, 0.1 mm per sample
    x = x + np.random.default_rng(1).normal(0, 0.3e-3, t.size)
    assert not hampel_mask(x, detrend=True).any()
    x[500] += 0.01
    assert np.flatnonzero(hampel_mask(x, detrend=True)).tolist() == [500]


def test_noise_estimate_is_robust_to_glitches():
    v = np.random.default_rng(2).normal(0, 1e-3, 100_000) + np.linspace(0, 10, 100_000)
    v[::1000] += 5.0
    assert noise_sigma_mm(v) == pytest.approx(1e-3, rel=0.05)


def test_outlier_settings_are_validated():
    with pytest.raises(InputError, match="window_samples"):
        OutlierSettings(window_samples=4)
    with pytest.raises(InputError, match="max_fraction"):
        OutlierSettings(max_fraction=1.5)
    with pytest.raises(InputError, match="differ in length"):
        encoder_outliers(np.zeros(5), np.zeros(6))


def test_sampling_scatter_within_its_bound_is_not_an_outlier():
    # separate (unlatched) reads: the table lags the motor by 0-2 servo cycles at random,
    # l_a - l_0 jumps on a lattice of speed x cycle (33 µm at 1000 mm/min and 500 Hz)
    rng = np.random.default_rng(4)
    n, v_mm_s, dt = 2000, 1000.0 / 60.0, 2e-3
    t = np.arange(n) * dt
    motor = v_mm_s * t
    table = motor - v_mm_s * dt * rng.choice([1] * 30 + [0, 2], n)  # mostly one cycle, now and then 0 or 2
    assert encoder_outliers(motor, table, time_s=t).sum() > 0.01 * n  # unexplained, they look like glitches
    bound_um = v_mm_s * 2 * dt * 1e3  # skew x speed
    assert not encoder_outliers(motor, table, time_s=t, sampling_bound_um=bound_um).any()
    table[700] += 5.0  # a real glitch still is one
    assert np.flatnonzero(encoder_outliers(motor, table, time_s=t, sampling_bound_um=bound_um)).tolist() == [700]


def test_time_stamp_scatter_within_its_bound_is_not_an_outlier():
    # polled, latched reads: each pair is consistent, but it is stamped at the middle of its
    # request, not when the controller latched it; on a loaded host a request takes up to
    # ~10 ms, so a stamp may be off by ±5 ms: 83 µm at 1000 mm/min (requests follow each
    # other, so the stamps still increase)
    rng = np.random.default_rng(5)
    n, v_mm_s, dt, u_s = 3000, 1000.0 / 60.0, 12e-3, 5e-3
    latched_at = np.arange(n) * dt
    stamped = latched_at + rng.uniform(-u_s, u_s, n) * (rng.random(n) < 0.05)  # 5 % of the requests were slow
    motor = v_mm_s * latched_at
    table = motor - 0.006
    assert encoder_outliers(motor, table, time_s=stamped).sum() > 0.01 * n  # unexplained, they look like glitches
    assert not encoder_outliers(motor, table, time_s=stamped, clock_uncertainty_s=u_s).any()
    assert not encoder_outliers(motor, table, time_s=latched_at).any()  # the stamps were all it was
    table[1700] += 0.005  # a glitch of one encoder still is one: the motor-table difference does not move in time
    assert np.flatnonzero(encoder_outliers(motor, table, time_s=stamped, clock_uncertainty_s=u_s)).tolist() == [1700]
    r = analyze_round_trip(*_polled(u_s), AXIS, uncertainty=UncertaintyInputs(clock_uncertainty_s=u_s))
    assert r.clock_uncertainty_s == u_s and r.to_dict()["clock_uncertainty_s"] == u_s
    with pytest.raises(OutlierError, match="outliers"):
        analyze_round_trip(*_polled(u_s), AXIS)


def _polled(u_s):
    """A round trip polled every 12.5 ms, 5 % of its stamps off by up to ``u_s``."""
    s = _trip(rate_hz=80.0)
    rng = np.random.default_rng(6)
    n = s.time_s.size
    stamped = s.time_s + rng.uniform(-u_s, u_s, n) * (rng.random(n) < 0.05)
    return stamped, s.motor_rev, s.table_mm
