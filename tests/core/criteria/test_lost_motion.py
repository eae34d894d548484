"""ISO 230-2 reversal values and the clearance behind them, on the twin."""

import warnings

import numpy as np
import pytest

from core.criteria import analyze_round_trip
from core.criteria.lost_motion import clearance_from_feeds, reversal_targets_mm, stroke_lost_motion
from core.criteria.segmentation import Stroke
from core.errors import InputError
from core.sim import AxisModel, Compliance, Effects, Friction, round_trip, simulate

CLEARANCE_UM = 20.0
COULOMB_N, VISCOUS_N_S_PER_MM, GUIDE_N_S_PER_MM, STIFFNESS_N_PER_UM = 1000.0, 5.0, 1.0, 200.0


def _trip(axis, feeds, rate_hz=500):
    """One program of round trips over 0..100 mm at each of ``feeds``, back to back."""
    parts = [simulate({"y": axis}, round_trip(0, 100, f), rate_hz=rate_hz) for f in feeds]
    t, m, x, t0 = [], [], [], 0.0
    for p in parts:
        t.append(p.time_s - p.time_s[0] + t0)
        m.append(p.motor_rev["y"])
        x.append(p.table_mm["y"])
        t0 = t[-1][-1] + 1.0 / rate_hz
    return analyze_round_trip(np.concatenate(t), np.concatenate(m), np.concatenate(x),
                              axis.to_axis_spec((10, 90)))


def _friction_axis():
    return AxisModel(backlash_um=CLEARANCE_UM, effects=Effects(
        friction=Friction(coulomb_n=COULOMB_N, viscous_n_s_per_mm=VISCOUS_N_S_PER_MM),
        compliance=Compliance(stiffness_n_per_um=STIFFNESS_N_PER_UM, guide_damping_n_s_per_mm=GUIDE_N_S_PER_MM)))


def _wind_up_um(feed_mm_min):
    # the nut loads the chain to the friction force in each direction: 2 F(v) / k
    force_n = COULOMB_N + (VISCOUS_N_S_PER_MM + GUIDE_N_S_PER_MM) * feed_mm_min / 60.0
    return 2.0 * force_n / STIFFNESS_N_PER_UM


def test_reversal_mean_equals_b_mean_on_a_pure_backlash_chain():
    res = _trip(AxisModel(backlash_um=CLEARANCE_UM), [2000])
    lm = res.lost_motion
    assert lm.mean_um == pytest.approx(res.backlash.mean_um, abs=0.01)
    assert lm.mean_um == pytest.approx(CLEARANCE_UM, abs=0.05)
    assert lm.max_abs_um == pytest.approx(CLEARANCE_UM, abs=0.05)
    assert lm.reversal_um.size == lm.target_mm.size >= 5
    assert lm.target_mm[0] == 10 and lm.target_mm[-1] == 90
    # one feed: the clearance cannot be separated, and the result says why
    assert lm.clearance.clearance_um is None and "one feed" in lm.clearance.reason
    d = res.to_dict()
    assert d["reversal_mean_um"] == lm.mean_um and d["reversal_max_um"] == lm.max_abs_um
    assert d["clearance_um"] is None and "total lost motion" in d["lost_motion"]["tbe_basis"]


def test_reversal_mean_exceeds_the_clearance_by_the_friction_lost_motion():
    feed = 2000.0
    res = _trip(_friction_axis(), [feed])
    assert res.lost_motion.mean_um - CLEARANCE_UM == pytest.approx(_wind_up_um(feed), abs=0.3)
    assert res.lost_motion.mean_um == pytest.approx(res.backlash.mean_um, abs=0.05)


def test_two_feeds_in_one_program_give_the_feed_independent_part():
    res = _trip(_friction_axis(), [500, 3000])
    c = res.lost_motion.clearance
    assert c.source == "program" and len(c.feeds_mm_min) == 2
    # feed 0 leaves the clearance plus the Coulomb wind-up, which is said
    assert c.clearance_um == pytest.approx(CLEARANCE_UM + _wind_up_um(0.0), abs=0.5)
    assert c.clearance_um - c.clearance_uncertainty_um <= CLEARANCE_UM + _wind_up_um(0.0) + 0.5
    slope = 2.0 * (VISCOUS_N_S_PER_MM + GUIDE_N_S_PER_MM) / STIFFNESS_N_PER_UM * 1000.0 / 60.0
    assert c.slope_um_per_m_min == pytest.approx(slope, rel=0.1)
    assert "Coulomb" in c.reason


def test_clearance_fit_from_a_history_with_temperature():
    rng = np.random.default_rng(3)
    feed = rng.choice([1000.0, 2000.0, 4000.0], 40)
    temp = rng.uniform(18, 28, 40)
    lost = 25.0 + 0.8 * feed / 1000.0 + 2.5 * (temp - 20.0) + rng.normal(0, 0.2, 40)
    c = clearance_from_feeds(feed, lost, source="history", temperature_c=temp)
    assert abs(c.clearance_um - 25.0) <= c.clearance_uncertainty_um
    assert c.slope_um_per_m_min == pytest.approx(0.8, abs=0.1)
    one = clearance_from_feeds([2000.0] * 5, [30.0] * 5, source="history")
    assert one.clearance_um is None and "one feed" in one.reason
    with pytest.raises(InputError):
        clearance_from_feeds([1.0, 2.0], [1.0])


def test_reversal_targets_follow_iso_230_2_counts():
    assert reversal_targets_mm(0, 100).size == 11
    assert reversal_targets_mm(0, 3000).size == 16  # 5 per metre


def test_a_hole_in_the_trace_leaves_its_bins_out_of_the_stroke_lost_motion_without_a_warning():
    """Two strokes each way over 0..100 mm at 1000 mm/min, the negative ones 20 µm behind;
    the second positive stroke lost its samples over 20..40 mm and the first positive one
    over 0..40 mm, so the bins there have no positive samples at all: they are left out
    (np.nanmean warned on them), and every other bin gives the 20 µm."""
    t = np.arange(6001) * 1e-3  # 1 kHz, 6 s: four strokes of 1.5 s, 100 mm each
    travel = np.concatenate([np.linspace(0, 100, 1501), np.linspace(100, 0, 1501)[1:],
                             np.linspace(0, 100, 1501)[1:], np.linspace(100, 0, 1501)[1:]])
    strokes = [Stroke(1, 0, 0, 1500), Stroke(-1, 1500, 1501, 3000), Stroke(1, 3000, 3001, 4500),
               Stroke(-1, 4500, 4501, 6000)]
    dev = np.zeros(t.size)
    for s in strokes:
        if s.direction < 0:
            dev[s.engaged : s.end + 1] = 0.020
    hole = np.zeros(t.size, bool)
    hole[:601] = True  # first positive stroke: 0..40 mm
    hole[3301:3601] = True  # second: 20..40 mm
    for a in (travel, dev):
        a[hole] = np.nan
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        feeds, lost, unc = stroke_lost_motion(t, travel, dev, strokes, 0.0, 100.0, 1, n_bins=10)
    assert feeds == pytest.approx([4000.0], rel=1e-3)
    assert lost == pytest.approx([20.0], abs=1e-9) and unc == pytest.approx([0.0], abs=1e-9)
