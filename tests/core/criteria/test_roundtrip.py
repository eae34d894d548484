"""Round-trip analysis on exact synthetic traces with known b(x) and lead error."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from core.criteria import analyze_round_trip
from core.dataset import AxisSpec
from core.errors import TraceError
from tests.core.criteria.synth import round_trip, true_criteria

AXIS = AxisSpec("y", 6.857, 16.0, 10.0, (0.0, 600.0))


def backlash(u):
    return 120.0 + 12.0 * np.sin(2 * np.pi * u / 450.0) + 0.01 * u


def lead_error(u):
    # sinusoids at the screw lead and at 300 mm, and a linear slope (e_p)
    return 4.0 * np.sin(2 * np.pi * u / 16.0 + 0.3) + 6.0 * np.sin(2 * np.pi * u / 300.0 + 1.0) - 0.02 * u


TRUE_B, TRUE_POS, TRUE_NEG = true_criteria(0.0, 600.0, backlash, lead_error)
CRITERIA = ("e_p_um", "v_u_um", "v_300_um", "v_2pi_um")


@pytest.mark.parametrize("feed_mm_min", [100, 1000, 5000])
@pytest.mark.parametrize("dwell_s", [0.0, 0.5])
def test_recovers_backlash_and_lead_criteria(feed_mm_min, dwell_s):
    s = round_trip(
        start_mm=-5.0, end_mm=605.0, feed_mm_min=feed_mm_min, dwell_s=dwell_s,
        backlash_um=backlash, lead_error_um=lead_error, table_noise_um=0.3, motor_noise_um=0.3,
        rng=np.random.default_rng(feed_mm_min),
    )
    r = analyze_round_trip(s.time_s, s.motor_rev, s.table_mm, AXIS)
    assert r.backlash.mean_um == pytest.approx(TRUE_B, abs=0.5)
    for name, truth in (("positive", TRUE_POS), ("negative", TRUE_NEG)):
        for key in CRITERIA:
            assert getattr(r.strokes[name], key) == pytest.approx(getattr(truth, key), abs=1.0), (name, key)
    # the profile itself, not only its mean
    assert r.backlash.backlash_um == pytest.approx(backlash(r.backlash.position_mm), abs=1.0)


def test_recovers_without_acceleration_ramps_and_over_several_cycles():
    s = round_trip(start_mm=-5.0, end_mm=605.0, feed_mm_min=2000, accel_mm_s2=None, cycles=3,
                   backlash_um=backlash, lead_error_um=lead_error)
    r = analyze_round_trip(s.time_s, s.motor_rev, s.table_mm, AXIS)
    assert r.strokes["positive"].n_strokes == 3
    assert r.strokes["negative"].n_strokes == 3
    assert r.backlash.mean_um == pytest.approx(TRUE_B, abs=0.5)


def test_top_level_dict_reports_positive_stroke_with_units():
    s = round_trip(start_mm=-5.0, end_mm=605.0, feed_mm_min=1000, backlash_um=backlash, lead_error_um=lead_error)
    d = analyze_round_trip(s.time_s, s.motor_rev, s.table_mm, AXIS).to_dict(curves=True)
    for key in ("backlash_mean_um", "backlash_min_um", "backlash_max_um", "e_p_um", "v_u_um", "v_300_um", "v_2pi_um"):
        assert isinstance(d[key], float)
    assert d["v_u_um"] == d["strokes"]["positive"]["v_u_um"]
    assert set(d["strokes"]) == {"positive", "negative"}
    assert len(d["curves"]["position_mm"]) == len(d["curves"]["backlash_um"])
    assert d["peak_speed_mm_min"] == pytest.approx(1000, rel=0.05)


@settings(max_examples=20, deadline=None)
@given(
    b0=st.floats(0.0, 300.0),
    ripple=st.floats(0.0, 1.0),
    period_mm=st.floats(30.0, 600.0),
    feed=st.sampled_from([300, 1500, 4000]),
)
def test_backlash_is_non_negative_for_a_pure_backlash_chain(b0, ripple, period_mm, feed):
    # Nothing but backlash in the chain (Eq. 5): any width profile b(x) >= 0, no lead error.
    # (With a lead error too, b is exact only to the grid's second-order error, a few nm:
    # the recovery tests bound that.)
    def b_fn(u):
        return b0 * (1.0 + ripple * np.sin(2 * np.pi * u / period_mm)) + 0.0 * u

    axis = AxisSpec("y", 6.857, 16.0, 10.0, (0.0, 200.0))
    s = round_trip(start_mm=-5.0, end_mm=205.0, feed_mm_min=feed, backlash_um=b_fn,
                   lead_error_um=lambda u: 0.0 * u, table_noise_um=0.0)
    r = analyze_round_trip(s.time_s, s.motor_rev, s.table_mm, axis)
    # exact up to the float resolution of positions of ~200 mm (1e-16 relative = 2e-11 µm)
    assert r.backlash.min_um >= -1e-9


@settings(max_examples=20, deadline=None)
@given(lead_amp=st.floats(0.0, 20.0), long_amp=st.floats(0.0, 20.0), noise=st.floats(0.0, 1.0))
def test_travel_variations_are_ordered(lead_amp, long_amp, noise):
    def e_fn(u):
        return lead_amp * np.sin(2 * np.pi * u / 16.0) + long_amp * np.sin(2 * np.pi * u / 500.0)

    s = round_trip(start_mm=-5.0, end_mm=605.0, feed_mm_min=3000, backlash_um=lambda u: 50 + 0 * u,
                   lead_error_um=e_fn, table_noise_um=noise)
    r = analyze_round_trip(s.time_s, s.motor_rev, s.table_mm, AXIS)
    for c in r.strokes.values():
        assert c.v_u_um >= c.v_300_um >= c.v_2pi_um >= 0.0


# ---- bad input: a typed error that names the problem ----

def _good():
    return round_trip(start_mm=-5.0, end_mm=605.0, feed_mm_min=3000, backlash_um=backlash, lead_error_um=lead_error)


def test_nan_sample_is_named():
    s = _good()
    s.table_mm[1234] = np.nan
    with pytest.raises(TraceError, match="table_mm has a NaN or inf sample at index 1234"):
        analyze_round_trip(s.time_s, s.motor_rev, s.table_mm, AXIS)


def test_inf_motor_sample_is_named():
    s = _good()
    s.motor_rev[7] = np.inf
    with pytest.raises(TraceError, match="motor_rev has a NaN or inf sample at index 7"):
        analyze_round_trip(s.time_s, s.motor_rev, s.table_mm, AXIS)


def test_time_not_increasing_is_named():
    s = _good()
    s.time_s[500] = s.time_s[499]
    with pytest.raises(TraceError, match="time_s not strictly increasing at index 500"):
        analyze_round_trip(s.time_s, s.motor_rev, s.table_mm, AXIS)


def test_single_stroke_is_rejected():
    s = _good()
    half = s.time_s.size // 2
    with pytest.raises(TraceError, match="a stroke in each direction"):
        analyze_round_trip(s.time_s[:half], s.motor_rev[:half], s.table_mm[:half], AXIS)


def test_travel_shorter_than_useful_travel_is_rejected():
    s = round_trip(start_mm=-5.0, end_mm=400.0, feed_mm_min=3000, backlash_um=backlash, lead_error_um=lead_error)
    with pytest.raises(TraceError, match="shorter than the useful travel 0..600"):
        analyze_round_trip(s.time_s, s.motor_rev, s.table_mm, AXIS)


def test_useful_travel_can_be_narrowed():
    s = round_trip(start_mm=-5.0, end_mm=400.0, feed_mm_min=3000, backlash_um=backlash, lead_error_um=lead_error)
    r = analyze_round_trip(s.time_s, s.motor_rev, s.table_mm, AXIS, useful_travel_mm=(0.0, 390.0))
    assert r.useful_travel_mm == (0.0, 390.0)


def test_motor_that_does_not_move_is_rejected():
    t = np.arange(1000) * 1e-3
    with pytest.raises(TraceError, match="motor does not move"):
        analyze_round_trip(t, np.full(t.size, 3.0), np.full(t.size, 20.0), AXIS)


def test_wrong_transmission_ratio_is_rejected():
    s = _good()
    wrong = AxisSpec("y", 6.857 * 1.08, 16.0, 10.0, (0.0, 600.0))
    with pytest.raises(TraceError, match="check transmission_mm_per_rev"):
        analyze_round_trip(s.time_s, s.motor_rev, s.table_mm, wrong)


def test_table_in_wrong_units_is_rejected():
    s = _good()
    with pytest.raises(TraceError, match="disagree"):
        analyze_round_trip(s.time_s, s.motor_rev, s.table_mm * 1000.0, AXIS)  # µm given as mm


def test_lost_samples_are_not_interpolated_over():
    s = _good()
    keep = np.ones(s.time_s.size, bool)
    i0 = np.searchsorted(s.time_s, 4.0)
    keep[i0 : i0 + 200] = False  # 10 mm of travel at 3000 mm/min
    with pytest.raises(TraceError, match="no samples between"):
        analyze_round_trip(s.time_s[keep], s.motor_rev[keep], s.table_mm[keep], AXIS)


def test_mismatched_lengths_and_too_short_traces():
    s = _good()
    with pytest.raises(TraceError, match="differ in length"):
        analyze_round_trip(s.time_s, s.motor_rev[:-1], s.table_mm, AXIS)
    with pytest.raises(TraceError, match="at least 10 samples"):
        analyze_round_trip(s.time_s[:5], s.motor_rev[:5], s.table_mm[:5], AXIS)


def test_table_that_never_follows_is_rejected():
    s = _good()
    table = np.where(s.time_s > s.time_s[-1] / 2, s.table_mm.max(), s.table_mm)  # chain broken at the far end
    with pytest.raises(TraceError):
        analyze_round_trip(s.time_s, s.motor_rev, table, AXIS)


def test_peak_speed_is_not_inflated_by_encoder_noise_at_high_sample_rates():
    # 0.3 µm noise at 10 kHz would add ~250 mm/min to a sample-to-sample speed
    axis = AxisSpec("y", 6.857, 16.0, 10.0, (0.0, 100.0))
    s = round_trip(start_mm=-5.0, end_mm=105.0, feed_mm_min=1000, rate_hz=10000.0, backlash_um=backlash,
                   lead_error_um=lead_error, table_noise_um=0.3, motor_noise_um=0.3)
    r = analyze_round_trip(s.time_s, s.motor_rev, s.table_mm, axis)
    assert r.peak_speed_mm_min == pytest.approx(1000.0, rel=0.02)


def _play_trip(waypoints_mm, backlash_mm=0.020, feed_mm_min=1000.0, rate_hz=1000.0, dwell_s=0.2):
    """Piecewise-constant-speed moves through ``waypoints_mm`` with dwells, and a pure play
    of ``backlash_mm`` between nut and table (Eq. 5): the exact b everywhere."""
    v = feed_mm_min / 60.0
    parts = []
    for a, c in zip(waypoints_mm[:-1], waypoints_mm[1:]):
        parts.append(np.linspace(a, c, max(2, int(abs(c - a) / v * rate_hz)), endpoint=False))
        parts.append(np.full(int(dwell_s * rate_hz), float(c)))
    nut = np.concatenate(parts + [[waypoints_mm[-1]]])
    table = np.empty_like(nut)
    x = nut[0] - backlash_mm / 2
    for i, u in enumerate(nut):
        x = min(max(x, u - backlash_mm / 2), u + backlash_mm / 2)
        table[i] = x
    return np.arange(nut.size) / rate_hz, nut / 10.0, table


@pytest.mark.parametrize("waypoints", [(0, 150, 149.5, 300, 0), (0, 150, 130, 300, 0), (0, 290, 289, 300, 0)])
def test_a_reversal_mid_stroke_does_not_pollute_the_profile_or_the_criteria(waypoints):
    # the motor goes back a little mid-stroke: the table re-engages after it, and that
    # transient must be dropped like the one at a turning point (it once gave min 13.8 µm
    # and v_u 7.8 µm on this pure 20 µm play)
    axis = AxisSpec("x", 10.0, 10.0, 30.0, (10.0, 290.0))
    r = analyze_round_trip(*_play_trip(waypoints), axis)
    b = r.backlash
    assert (b.mean_um, b.min_um, b.max_um) == pytest.approx((20.0, 20.0, 20.0), abs=0.01)
    assert r.strokes["positive"].v_u_um < 0.01


def test_a_reversal_that_leaves_too_little_of_the_stroke_is_a_clear_error():
    axis = AxisSpec("x", 10.0, 10.0, 30.0, (10.0, 290.0))
    with pytest.raises(TraceError, match="shorter than the useful travel"):
        analyze_round_trip(*_play_trip((0, 20, 19, 300, 0)), axis)


def test_a_long_dwell_neither_hides_the_motion_nor_lowers_the_peak_speed():
    # 0.6 s of motion each way in 800 s of dwell, encoders quantised: once "the motor does
    # not move", and a peak speed of 0 mm/min from a percentile over all samples
    axis = AxisSpec("x", 10.0, 10.0, 30.0, (10.0, 290.0))
    t, motor_rev, table_mm = _play_trip((0, 300, 0), feed_mm_min=10000.0, dwell_s=400.0)
    motor_rev, table_mm = np.rint(motor_rev * 2**20) / 2**20, np.rint(table_mm * 1e4) / 1e4
    r = analyze_round_trip(t, motor_rev, table_mm, axis)
    assert r.backlash.mean_um == pytest.approx(20.0, abs=0.01)
    assert r.peak_speed_mm_min == pytest.approx(10000.0, rel=0.01)


def test_text_in_a_trace_is_a_trace_error():
    words = np.array(["time_s"] + ["1.0"] * 19)  # a header row read as data
    with pytest.raises(TraceError, match="time_s must hold numbers"):
        analyze_round_trip(words, np.zeros(20), np.zeros(20), AXIS)


# ---- any sampling density ----

AXIS_200 = AxisSpec("y", 6.857, 16.0, 10.0, (0.0, 200.0))
TRUE_B_200, TRUE_POS_200, TRUE_NEG_200 = true_criteria(0.0, 200.0, backlash, lead_error)


@pytest.mark.parametrize("noise_um", [0.05, 0.3])
@pytest.mark.parametrize(
    ("feed_mm_min", "rate_hz"),
    [(100, 100), (100, 1000), (2000, 4000), (4000, 250), (8000, 200), (10000, 100)],
)
def test_accuracy_envelope_over_feeds_rates_and_noise(feed_mm_min, rate_hz, noise_um):
    # 8000 mm/min at 200 Hz puts 0.67 mm between samples, 10,000 at 100 Hz 1.67 mm:
    # most 0.25 mm bins hold no sample, so the curve is interpolated within each stroke.
    s = round_trip(
        start_mm=-3.0, end_mm=203.0, feed_mm_min=feed_mm_min, rate_hz=rate_hz,
        backlash_um=backlash, lead_error_um=lead_error,
        table_noise_um=noise_um, motor_noise_um=noise_um, rng=np.random.default_rng(feed_mm_min + rate_hz),
    )
    r = analyze_round_trip(s.time_s, s.motor_rev, s.table_mm, AXIS_200)
    assert r.backlash.mean_um == pytest.approx(TRUE_B_200, abs=0.5)
    for name, truth in (("positive", TRUE_POS_200), ("negative", TRUE_NEG_200)):
        for key in CRITERIA:
            assert getattr(r.strokes[name], key) == pytest.approx(getattr(truth, key), abs=1.0), (name, key)
    d = r.to_dict()
    assert d["grid_step_mm"] == 0.25 and d["grid_points"] == 801
    assert d["sample_spacing_mm"] == pytest.approx(feed_mm_min / 60.0 / rate_hz, rel=0.05)


def test_sparse_samples_widen_the_smoothing_but_not_beyond_a_quarter_lead():
    s = round_trip(start_mm=-3.0, end_mm=203.0, feed_mm_min=10000, rate_hz=100, backlash_um=backlash,
                   lead_error_um=lead_error)
    r = analyze_round_trip(s.time_s, s.motor_rev, s.table_mm, AXIS_200)
    assert r.smoothing_mm == pytest.approx(4.0)  # 4 x 1.67 mm, capped at 16 mm / 4
    dense = round_trip(start_mm=-3.0, end_mm=203.0, feed_mm_min=1000, rate_hz=1000, backlash_um=backlash,
                       lead_error_um=lead_error)
    assert analyze_round_trip(dense.time_s, dense.motor_rev, dense.table_mm, AXIS_200).smoothing_mm == 2.0


def test_a_hole_just_over_max_gap_is_refused_even_on_a_sparse_trace():
    s = round_trip(start_mm=-3.0, end_mm=203.0, feed_mm_min=8000, rate_hz=200, backlash_um=backlash,
                   lead_error_um=lead_error)
    keep = np.ones(s.time_s.size, bool)
    i0 = int(np.searchsorted(s.time_s, 1.0))
    keep[i0 : i0 + 3] = False  # 4 x 0.67 mm = 2.67 mm between two kept samples
    with pytest.raises(TraceError, match=r"no samples between .* > max_gap_mm 2 mm"):
        analyze_round_trip(s.time_s[keep], s.motor_rev[keep], s.table_mm[keep], AXIS_200)
    keep[i0 + 2] = True  # now 2.0 mm: interpolated over
    analyze_round_trip(s.time_s[keep], s.motor_rev[keep], s.table_mm[keep], AXIS_200)
