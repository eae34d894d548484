"""The compliance form's damping floor: the position loop closed on the table through the
chain must be stable (a machine that makes parts is), which the open-loop round-trip fit
cannot see and the closed-loop contour simulation depends on. The friction chain has no
floor: its friction bounds the cycle."""

import math

import numpy as np
import pytest

from core.gap import candidates as C


def _max_real_root(k, w, g, zeta):
    return float(np.max(np.roots([1.0, 2 * zeta * w + g, w * w + 2 * zeta * w * k, k * w * w]).real))


@pytest.mark.parametrize("k, fn, g", [(8.0, 15.0, 0.0), (32.0, 32.6, 0.0), (40.0, 30.0, 1.0), (25.0, 120.0, 5.0),
                                      (40.0, 5.0, 2.0)])
def test_the_floor_is_where_the_closed_loop_turns_unstable(k, fn, g):
    w = 2 * math.pi * fn
    floor = C.loop_damping_floor(k, w, g)
    assert floor > 0.0
    assert _max_real_root(k, w, g, floor * 1.01) < 0.0
    assert _max_real_root(k, w, g, floor * 0.99) > 0.0
    assert floor == pytest.approx((k - g) / (2 * w), rel=0.5)  # the small-damping estimate


def test_guide_damping_at_least_the_gain_needs_no_chain_damping():
    assert C.loop_damping_floor(10.0, 2 * math.pi * 40.0, 10.0) == 0.0
    assert C.loop_damping_floor(10.0, 2 * math.pi * 40.0, 25.0) == 0.0
    assert _max_real_root(10.0, 2 * math.pi * 40.0, 25.0, 1e-4) < 0.0


def test_the_compliance_stage_penalises_only_an_unstable_loop():
    comp = C.compliance_stage(32.0)
    floor = C.loop_damping_floor(32.0, 2 * math.pi * 32.6, 0.0)
    stable, unstable = np.array([32.6, 1.2 * floor, 0.0, 196.0]), np.array([32.6, 0.3 * floor, 0.0, 196.0])
    assert comp.prior(stable)[1] == 0.0
    assert comp.prior(unstable)[1] == pytest.approx(0.7 * C.LOOP_STABILITY_WEIGHT)
    edge = np.array([32.6, floor * (1 - 1e-6), 0.0, 196.0])
    assert comp.prior(edge)[1] < 1.0  # continuous at the floor: no step in the cost
    assert C.compliance_stage().prior(unstable)[1] == 0.0  # no gain known: no floor
    # friction bounds a chain's oscillation (a hunting cycle): the friction chain has no floor
    assert C.friction_chain_stage().prior is None


@pytest.mark.parametrize("factor, bounded", [(1.3, True), (0.5, False)])
def test_the_floor_separates_a_bounded_from_a_diverging_closed_loop_simulation(factor, bounded):
    """The twin's closed-loop simulation (the contour form) of a chain fitted at 32.6 Hz
    with no guide damping on an axis with K = 32/s and no backlash (independent 9401
    case 27's axis x): above the floor the tracking error stays that of a P loop at
    this feed; below it the loop rings up without bound."""
    from core.sim import AxisModel, Effects, round_trip, simulate

    k, fn = 32.0, 32.6
    floor = C.loop_damping_floor(k, 2 * math.pi * fn, 0.0)
    piece, _ = C.sim_piece("compliance", {"natural_frequency_hz": fn, "damping_ratio": factor * floor,
                                          "guide_damping_per_s": 0.0, "guide_friction_mm_s2": 0.0}, {}, None, 0.0)
    axis = AxisModel(name="x", position_gain_per_s=k, effects=Effects().with_effect("compliance", piece))
    tr = simulate({"x": axis}, round_trip(0.0, 30.0, 1200.0, axis="x"), rate_hz=500.0)
    err_um = 1e3 * np.abs(tr.table_true_mm["x"] - tr.command_mm["x"])
    lag_um = 1e3 * 1200.0 / 60.0 / k  # the P loop's following error at this feed
    if bounded:
        assert np.all(np.isfinite(err_um)) and np.max(err_um) < 2.0 * lag_um
    else:
        assert not np.all(np.isfinite(err_um)) or np.max(err_um) > 100.0 * lag_um
