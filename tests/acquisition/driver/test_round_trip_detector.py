"""The passive round-trip detector on synthetic streams: what it finds, what it passes over,
and that the way a stream is cut into blocks never changes the answer."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from acquisition.errors import IncompleteRoundTrip, NoRoundTripSeen, RoundTripTooLong
from acquisition.driver.round_trip_detector import DetectorSettings, RoundTripDetector
from core.errors import InputError

RATE_HZ = 1000.0
K_A = 6.857  # mm per motor revolution
CFG = DetectorSettings(start_timeout_s=30.0, max_duration_s=20.0, rest_band_mm=0.005, rest_s=0.1,
                       min_stroke_mm=10.0, return_tolerance_mm=1.0)


def path(points_mm, speeds_mm_s, rests_s, rng, *, noise_mm=0.001, t0_s=0.0):
    """Piecewise-linear table motion: rest rests_s[0] at points[0], move to points[1] at
    speeds[0], rest rests_s[1], ... Uniform encoder noise of +-noise_mm (peak to peak 2x).
    Returns t_s, motor_rev, table_mm and the true (start, reversal, end) times of motion."""
    xs, times = [np.full(int(rests_s[0] * RATE_HZ), points_mm[0])], []
    for i in range(1, len(points_mm)):
        a, b = points_mm[i - 1], points_mm[i]
        n = max(2, int(abs(b - a) / speeds_mm_s[i - 1] * RATE_HZ))
        times.append(sum(len(p) for p in xs) / RATE_HZ)
        xs.append(np.linspace(a, b, n + 1)[1:])
        times.append(sum(len(p) for p in xs) / RATE_HZ)
        xs.append(np.full(int(rests_s[i] * RATE_HZ), b))
    x = np.concatenate(xs)
    x = x + rng.uniform(-noise_mm, noise_mm, x.size)
    t = t0_s + np.arange(x.size) / RATE_HZ
    return t, x / K_A, x, times


def feed_in_blocks(det, t, m, x, cuts, running=None):
    """Feed the stream cut at ``cuts``; return the round trip, or None if the stream ran out."""
    edges = [0, *sorted(set(c for c in cuts if 0 < c < t.size)), t.size]
    for a, b in zip(edges[:-1], edges[1:]):
        r = det.feed(t[a:b], m[a:b], x[a:b], None if running is None else running[a:b])
        if r is not None:
            return r
    return None


cuts_st = st.lists(st.integers(min_value=1, max_value=200_000), max_size=40)


@settings(max_examples=40)
@given(level=st.floats(-500, 500), noise=st.floats(0.0, 0.0025), seconds=st.floats(0.5, 25.0),
       cuts=cuts_st, seed=st.integers(0, 2**32 - 1))
def test_noise_at_rest_never_starts_a_round_trip(level, noise, seconds, cuts, seed):
    """Noise within the rest band (peak to peak <= rest_band_mm) is rest, however long."""
    rng = np.random.default_rng(seed)
    n = int(seconds * RATE_HZ)
    x = level + rng.uniform(-noise, noise, n)
    t = np.arange(n) / RATE_HZ
    det = RoundTripDetector(CFG)
    assert feed_in_blocks(det, t, x / K_A, x, cuts) is None
    assert det.phase == "waiting"
    with pytest.raises(NoRoundTripSeen, match="no round trip seen within 30 s"):
        det.finish()


def test_noise_at_rest_until_the_time_out_ends_with_no_round_trip_seen():
    rng = np.random.default_rng(3)
    n = int(31 * RATE_HZ)
    x = 12.0 + rng.uniform(-0.002, 0.002, n)
    t = 100.0 + np.arange(n) / RATE_HZ
    det = RoundTripDetector(CFG)
    with pytest.raises(NoRoundTripSeen, match="within 30 s") as err:
        feed_in_blocks(det, t, x / K_A, x, range(0, n, 500))
    assert err.value.reason_code == "no_round_trip" and err.value.waited_s == 30.0


@settings(max_examples=40)
@given(start=st.floats(-300, 300), stroke_frac=st.floats(0.0, 1.0), direction=st.sampled_from([-1.0, 1.0]),
       speed=st.floats(5.0, 60.0), dwell=st.floats(0.0, 1.0), rest_before=st.floats(0.15, 3.0),
       cuts_a=cuts_st, cuts_b=cuts_st, seed=st.integers(0, 2**32 - 1))
def test_any_stroke_above_the_minimum_is_found_whole_whatever_the_blocks(
        start, stroke_frac, direction, speed, dwell, rest_before, cuts_a, cuts_b, seed):
    rng = np.random.default_rng(seed)
    # from just above the minimum to what fits in max_duration_s (8 s each way)
    stroke = CFG.min_stroke_mm * 1.05 + stroke_frac * (8.0 * speed - CFG.min_stroke_mm * 1.05)
    far = start + direction * stroke
    t, m, x, (t_leave, t_far, t_back, t_home) = path([start, far, start], [speed, speed], [rest_before, dwell, 0.5],
                                                     rng)
    ra = feed_in_blocks(RoundTripDetector(CFG), t, m, x, cuts_a)
    rb = feed_in_blocks(RoundTripDetector(CFG), t, m, x, cuts_b)
    assert ra is not None and rb is not None
    # the same samples, however the stream was cut
    np.testing.assert_array_equal(ra.t_s, rb.t_s)
    np.testing.assert_array_equal(ra.table_mm, rb.table_mm)
    assert (ra.start_index, ra.reversal_index, ra.end_index) == (rb.start_index, rb.reversal_index, rb.end_index)
    # whole: rest before the first move, the far end, rest after the return
    assert ra.t_s[0] < t_leave and ra.t_s[-1] > t_home
    assert abs(ra.t_s[ra.start_index] - t_leave) < 0.02
    assert t_far - 0.01 <= ra.t_s[ra.reversal_index] <= t_back + 0.01
    assert abs(ra.stroke_mm - stroke) < 0.01
    assert ra.found_by == "positions"
    assert abs(ra.feed_mm_min - speed * 60) < 0.05 * speed * 60


def test_a_jog_short_of_the_minimum_stroke_is_passed_over_and_the_round_trip_after_it_found():
    rng = np.random.default_rng(5)
    t, m, x, times = path([0.0, 4.0, 0.0, 0.0, 50.0, 0.0], [20, 20, 20, 20, 20], [0.5, 0.2, 0.5, 0.0, 0.3, 0.5], rng)
    r = feed_in_blocks(RoundTripDetector(CFG), t, m, x, range(0, t.size, 64))
    assert r is not None and abs(r.stroke_mm - 50.0) < 0.01
    assert abs(r.t_s[r.start_index] - times[4]) < 0.02  # the second motion's start, not the jog's


def test_a_long_positioning_move_before_the_round_trip_is_passed_over():
    """The CNC brings the axis from 500 mm to the start, rests, then runs 0 -> 100 -> 0."""
    rng = np.random.default_rng(6)
    t, m, x, times = path([500.0, 0.0, 100.0, 0.0], [50, 20, 20], [0.5, 0.3, 0.3, 0.5], rng)
    r = feed_in_blocks(RoundTripDetector(CFG), t, m, x, range(0, t.size, 100))
    assert r is not None
    assert abs(r.start_mm) < 0.01 and abs(r.reversal_mm - 100.0) < 0.01
    assert abs(r.t_s[r.start_index] - times[2]) < 0.02


def test_motion_under_way_when_listening_begins_is_not_taken_halfway():
    """The first samples are mid-stroke: no rest before them, so no start there."""
    rng = np.random.default_rng(7)
    t, m, x, _ = path([0.0, 60.0, 0.0], [20, 20], [0.5, 0.2, 0.5], rng)
    k = int(1.0 * RATE_HZ)  # 0.5 s into the outward stroke
    det = RoundTripDetector(CFG)
    assert feed_in_blocks(det, t[k:], m[k:], x[k:], range(0, t.size, 50)) is None


def test_two_reversals_are_not_one_round_trip():
    """Out, back half way, out again, home: machining-like motion, not the round trip."""
    rng = np.random.default_rng(8)
    t, m, x, _ = path([0.0, 60.0, 30.0, 60.0, 0.0], [20] * 4, [0.5, 0.0, 0.0, 0.0, 0.5], rng)
    assert feed_in_blocks(RoundTripDetector(CFG), t, m, x, range(0, t.size, 77)) is None


def test_a_stroke_that_comes_to_rest_elsewhere_is_reported_incomplete_at_the_time_out():
    rng = np.random.default_rng(9)
    t, m, x, _ = path([0.0, 60.0, 20.0], [20, 20], [0.5, 0.2, 31.0], rng)
    with pytest.raises(IncompleteRoundTrip, match="came to rest at 20.0.*not back at its start") as err:
        feed_in_blocks(RoundTripDetector(CFG), t, m, x, range(0, t.size, 1000))
    assert err.value.reason_code == "incomplete_round_trip"


def test_a_stream_that_ends_mid_round_trip_is_incomplete():
    rng = np.random.default_rng(10)
    t, m, x, times = path([0.0, 60.0, 0.0], [20, 20], [0.5, 0.2, 0.5], rng)
    k = int(times[2] * RATE_HZ) + 200  # on the way back
    det = RoundTripDetector(CFG)
    assert feed_in_blocks(det, t[:k], m[:k], x[:k], range(0, k, 100)) is None
    assert det.phase == "moving"
    with pytest.raises(IncompleteRoundTrip, match="stream ended"):
        det.finish()


def test_a_round_trip_longer_than_max_duration_is_too_long():
    rng = np.random.default_rng(11)
    # a slow stroke: 2 x 200 mm at 10 mm/s = 40 s > max_duration_s 20 s
    t, m, x, _ = path([0.0, 200.0, 0.0], [10, 10], [0.5, 0.2, 0.5], rng)
    with pytest.raises(RoundTripTooLong, match="max_duration_s"):
        feed_in_blocks(RoundTripDetector(CFG), t, m, x, range(0, t.size, 1000))


# -- running flag ---------------------------------------------------------------------------
def flagged(rng, flag_from_s, flag_to_s, **kw):
    t, m, x, times = path(**kw, rng=rng)
    running = (t >= flag_from_s) & (t < flag_to_s)
    return t, m, x, running, times


@settings(max_examples=25)
@given(cuts=cuts_st, seed=st.integers(0, 2**32 - 1), margin=st.sampled_from([0.0, 0.05]))
def test_the_running_flag_gives_exactly_the_flagged_samples(cuts, seed, margin):
    rng = np.random.default_rng(seed)
    t, m, x, running, times = flagged(rng, 0.4, 6.9, points_mm=[0.0, 60.0, 0.0], speeds_mm_s=[20, 20],
                                      rests_s=[0.5, 0.2, 0.5])
    det = RoundTripDetector(DetectorSettings(**{**CFG.__dict__, "flag_margin_s": margin}), use_flag=True)
    r = feed_in_blocks(det, t, m, x, cuts, running)
    assert r is not None and r.found_by == "flag"
    on = t[running]
    assert r.t_s[r.start_index] == on[0] and r.t_s[r.end_index] == on[-1]
    assert r.t_s[0] == pytest.approx(on[0] - margin, abs=1.5 / RATE_HZ)
    assert abs(r.stroke_mm - 60.0) < 0.01


def test_a_flag_already_set_when_listening_begins_is_waited_out():
    rng = np.random.default_rng(12)
    # a first run under way at the start (flag set from sample 0), then a whole second one
    t1, m1, x1, _ = path([30.0, 0.0], [20], [0.0, 0.5], rng)
    t2, m2, x2, _ = path([0.0, 40.0, 0.0], [20, 20], [0.5, 0.2, 0.5], rng, t0_s=t1[-1] + 1e-3)
    t, m, x = np.concatenate([t1, t2]), np.concatenate([m1, m2]), np.concatenate([x1, x2])
    running = np.concatenate([t1 < t1[0] + 1.0, (t2 >= t2[0] + 0.3) & (t2 < t2[-1] - 0.3)])
    r = feed_in_blocks(RoundTripDetector(CFG, use_flag=True), t, m, x, range(0, t.size, 128), running)
    assert r is not None and abs(r.stroke_mm - 40.0) < 0.01 and r.t_s[0] > t2[0]


def test_a_flag_that_falls_away_from_the_start_is_incomplete():
    rng = np.random.default_rng(13)
    t, m, x, running, _ = flagged(rng, 0.4, 5.0, points_mm=[0.0, 60.0, 20.0], speeds_mm_s=[20, 20],
                                  rests_s=[0.5, 0.2, 0.5])
    with pytest.raises(IncompleteRoundTrip, match="flag fell"):
        feed_in_blocks(RoundTripDetector(CFG, use_flag=True), t, m, x, [1000], running)


def test_a_flag_that_never_rises_is_no_round_trip_seen_even_with_motion():
    rng = np.random.default_rng(14)
    t, m, x, _ = path([0.0, 60.0, 0.0, 0.0], [20, 20, 1], [0.5, 0.2, 28.0, 3.0], rng)
    with pytest.raises(NoRoundTripSeen, match="running flag never rose"):
        feed_in_blocks(RoundTripDetector(CFG, use_flag=True), t, m, x, range(0, t.size, 999),
                       np.zeros(t.size, dtype=bool))


def test_a_flag_set_too_long_is_too_long():
    rng = np.random.default_rng(15)
    t, m, x, running, _ = flagged(rng, 0.4, 1e9, points_mm=[0.0, 60.0, 60.0], speeds_mm_s=[20, 1],
                                  rests_s=[0.5, 22.0, 0.5])
    with pytest.raises(RoundTripTooLong, match="running flag"):
        feed_in_blocks(RoundTripDetector(CFG, use_flag=True), t, m, x, range(0, t.size, 500), running)


# -- bad input --------------------------------------------------------------------------------
@pytest.mark.parametrize("kw, field", [({"rest_s": 0}, "rest_s"), ({"min_stroke_mm": 1.5}, "min_stroke_mm"),
                                       ({"return_tolerance_mm": 0.001}, "return_tolerance_mm"),
                                       ({"start_timeout_s": -1}, "start_timeout_s"),
                                       ({"pre_roll_s": float("nan")}, "pre_roll_s")])
def test_bad_settings_name_the_field(kw, field):
    with pytest.raises(InputError, match=field):
        DetectorSettings(**kw)


def test_bad_samples_are_refused_with_what_is_wrong():
    det = RoundTripDetector(CFG)
    with pytest.raises(InputError, match="one length"):
        det.feed([0.0, 0.1], [0.0], [0.0, 0.0])
    with pytest.raises(InputError, match="table_mm is NaN"):
        det.feed([0.0, 0.1], [0.0, 0.0], [0.0, float("nan")])
    det.feed([0.0, 0.1], [0.0, 0.0], [0.0, 0.0])
    with pytest.raises(InputError, match="t_s must increase"):
        det.feed([0.1, 0.2], [0.0, 0.0], [0.0, 0.0])
    with pytest.raises(InputError, match="running="):
        RoundTripDetector(CFG, use_flag=True).feed([0.0], [0.0], [0.0])


def test_waiting_at_rest_for_long_keeps_only_the_pre_roll():
    """Hours at rest must not grow the buffer: only the last pre-roll is kept."""
    det = RoundTripDetector(DetectorSettings(**{**CFG.__dict__, "start_timeout_s": 1e6}))
    for k in range(200):
        t = k * 1.0 + np.arange(1000) / RATE_HZ
        det.feed(t, np.zeros(1000), np.zeros(1000))
    assert sum(c[1].size for c in det._chunks) <= 2000


def test_a_flag_set_from_the_first_sample_is_taken_when_the_wire_says_the_run_starts_there():
    """The wire read the controller's trace from the program's first record: not halfway."""
    rng = np.random.default_rng(16)
    t, m, x, running, _ = flagged(rng, 0.0, 6.9, points_mm=[0.0, 60.0, 0.0], speeds_mm_s=[20, 20],
                                  rests_s=[0.5, 0.2, 0.5])
    det = RoundTripDetector(CFG, use_flag=True)
    assert det.feed(t[:100], m[:100], x[:100], running[:100], run_start=True) is None
    r = feed_in_blocks(det, t[100:], m[100:], x[100:], range(0, t.size, 300), running[100:])
    assert r is not None and r.t_s[r.start_index] == t[0]
    # without the wire's word, the same stream is a run already under way: waited out
    det = RoundTripDetector(CFG, use_flag=True)
    assert feed_in_blocks(det, t, m, x, range(0, t.size, 300), running) is None
