"""The nominal model (rigid chain, ideal inner loops, P loop, Eq. 5) against the paper."""

import itertools

import numpy as np
import pytest
from hypothesis import example, given, settings
from hypothesis import strategies as st

from core.sim import AxisModel, Effects, ServoDynamics, circle, line, round_trip, simulate
from core.tbe.formulas import circle_delay_s, tbe_circle_um, tbe_line_um
from tests.core.sim.helpers import apparent_backlash_um


def _xy(b_um, gain):
    return {a: AxisModel(a, position_gain_per_s=gain, backlash_um=b_um) for a in ("x", "y")}


@pytest.mark.parametrize(
    ("b_um", "feed", "angle", "gain"),
    [(236.0, 200.0, 45.0, 10.0), (100.0, 1000.0, 30.0, 10.0), (50.0, 2000.0, 60.0, 25.0), (20.0, 3000.0, 15.0, 30.0)],
)
def test_line_tbe_matches_eq7(b_um, feed, angle, gain):
    tr = simulate(_xy(b_um, gain), line(angle, 30.0, feed), rate_hz=20000.0)
    th = np.radians(angle)
    contour_um = (tr.table_true_mm["y"] * np.cos(th) - tr.table_true_mm["x"] * np.sin(th)) * 1e3
    expected = float(tbe_line_um(b_um, angle, feed, gain))
    assert np.abs(contour_um).max() == pytest.approx(expected, rel=0.005)


def _circle_radii(b_um, radius, feed, gain, *, settle_s=None):
    """Radius with and without backlash around the quadrant point at 0 deg (x reverses)."""
    omega = feed / 60.0 / radius
    delay = float(circle_delay_s(b_um, radius, feed, gain))
    before = np.degrees(omega * (12.0 / gain if settle_s is None else settle_s))
    after = np.degrees(omega * (3 * delay + 3.0 / gain))
    prog = circle(radius, (0.0, 0.0), feed, "ccw", -before, before + after, lead_in_deg=0.0, lead_out_deg=0.0)
    rate = max(1000.0, 2000.0 / delay)
    out = []
    for b in (b_um, 0.0):
        tr = simulate(_xy(b, gain), prog, rate_hz=rate)
        out.append(np.hypot(tr.table_true_mm["x"], tr.table_true_mm["y"]))
    return out


GRID = list(itertools.product((20.0, 100.0, 300.0), (25.0, 70.0, 200.0), (100.0, 600.0, 3000.0), (10.0, 17.0, 30.0)))


@pytest.mark.parametrize(("b_um", "radius", "feed", "gain"), GRID)
def test_circle_tbe_matches_eqs_8_to_11(b_um, radius, feed, gain):
    with_b, without_b = _circle_radii(b_um, radius, feed, gain)
    got = (with_b - without_b).max() * 1e3
    assert got == pytest.approx(float(tbe_circle_um(b_um, radius, feed, gain)), rel=0.005)


@pytest.mark.parametrize(("b_um", "peak_um"), [(236.0, 44.68), (100.0, 23.98)])
def test_absolute_radial_peak_of_the_paper_example(b_um, peak_um):
    with_b, _ = _circle_radii(b_um, 200.0, 200.0, 10.0)
    assert (with_b.max() - 200.0) * 1e3 == pytest.approx(peak_um, rel=0.003)


def test_table_stays_within_the_backlash_and_is_pushed_at_its_bounds():
    b = 80.0
    tr = simulate({"y": AxisModel(backlash_um=b)}, round_trip(0.0, 30.0, 1000.0, dwell_s=0.3), rate_hz=2000.0)
    gap_um = (tr.nut_mm["y"] - tr.table_true_mm["y"]) * 1e3
    assert gap_um.min() >= -b / 2 - 1e-6 and gap_um.max() <= b / 2 + 1e-6
    v = np.gradient(tr.command_mm["y"], tr.time_s)
    steady = np.abs(np.gradient(tr.table_true_mm["y"], tr.time_s) - v) < 1e-6  # settled on the feed
    out = steady & (v > 0.99 * v.max())
    back = steady & (v < 0.99 * v.min())
    assert out.sum() > 100 and back.sum() > 100
    assert gap_um[out] == pytest.approx(np.full(out.sum(), b / 2), abs=1e-6)  # Eq. 5, feeding positively
    assert gap_um[back] == pytest.approx(np.full(back.sum(), -b / 2), abs=1e-6)
    assert apparent_backlash_um(tr, "y", 5.0, 25.0) == pytest.approx(b, abs=1e-6)


@pytest.mark.parametrize(("side", "sign"), [("positive", 1.0), ("negative", -1.0)])
def test_initial_side_puts_the_table_on_the_chosen_flank(side, sign):
    axis = AxisModel(backlash_um=100.0, initial_side=side)
    tr = simulate({"y": axis}, round_trip(0.0, 10.0, 600.0, dwell_s=0.5), rate_hz=100.0)
    assert tr.table_true_mm["y"][0] == pytest.approx(0.0)
    assert (tr.nut_mm["y"][0] - tr.table_true_mm["y"][0]) * 1e3 == pytest.approx(sign * 50.0)


def test_reversely_engaged_start_delays_the_table_by_the_backlash_traverse():
    prog = round_trip(0.0, 5.0, 600.0, acceleration_mm_s2=None, dwell_s=0.2)
    direct = simulate({"y": AxisModel(backlash_um=100.0, initial_side="positive")}, prog, rate_hz=10000.0)
    reverse = simulate({"y": AxisModel(backlash_um=100.0, initial_side="negative")}, prog, rate_hz=10000.0)
    t = direct.time_s
    moving = lambda tr: t[np.argmax(tr.table_true_mm["y"] > 1e-9)]  # noqa: E731
    # Eq. 6 with a ramp error e = v t: the integral K v T^2 / 2 reaches b at T = sqrt(2 b / (K v)).
    expected_delay = np.sqrt(2 * 0.1 / (10.0 * 10.0))
    assert moving(reverse) - moving(direct) == pytest.approx(expected_delay, abs=2e-4)


def test_motor_zero_is_nominal_travel_over_ka():
    axis = AxisModel(transmission_mm_per_rev=5.0, backlash_um=0.0)
    tr = simulate({"y": axis}, round_trip(10.0, 20.0, 600.0, dwell_s=0.5), rate_hz=100.0)
    assert tr.motor_rev["y"][0] * 5.0 == pytest.approx(10.0)
    assert tr.motor_rev["y"] * 5.0 == pytest.approx(tr.table_mm["y"], abs=1e-9)


@pytest.mark.parametrize(("b_um", "radius", "feed", "gain"), [(236.0, 200.0, 200.0, 10.0), (300.0, 25.0, 3000.0, 30.0)])
def test_the_fixed_step_integrator_reproduces_the_exact_one(b_um, radius, feed, gain):
    """Zero servo lag routes the same model through the fixed-step loop: a cross-check."""
    omega = feed / 60.0 / radius
    delay = float(circle_delay_s(b_um, radius, feed, gain))
    before, after = np.degrees(omega * 12.0 / gain), np.degrees(omega * (3 * delay + 3.0 / gain))
    prog = circle(radius, (0.0, 0.0), feed, "ccw", -before, before + after, lead_in_deg=0.0, lead_out_deg=0.0)
    tbe = []
    for fx in (Effects(), Effects(servo_dynamics=ServoDynamics(velocity_lag_s=0.0, dead_time_s=0.0))):
        radii = []
        for b in (b_um, 0.0):
            axes = {a: AxisModel(a, position_gain_per_s=gain, backlash_um=b, effects=fx) for a in ("x", "y")}
            tr = simulate(axes, prog, rate_hz=2000.0 / delay)
            radii.append(np.hypot(tr.table_true_mm["x"], tr.table_true_mm["y"]))
        tbe.append((radii[0] - radii[1]).max())
    assert tbe[1] == pytest.approx(tbe[0], rel=0.003)


@settings(max_examples=25, deadline=None)
@given(
    b_um=st.floats(0.0, 400.0),
    gain=st.floats(5.0, 40.0),
    feed=st.floats(50.0, 5000.0),
    travel=st.floats(1.0, 30.0),
)
# found by CI (hypothesis seed 1962026592): a zero-width play flipped between flank and gap
# at one instant until the step was cut short, leaving the table 0.8 nm off the nut
@example(b_um=0.0, gain=24.375, feed=1341.0, travel=1.0)
def test_property_nominal_table_stays_in_the_backlash_and_b_is_recovered(b_um, gain, feed, travel):
    axis = AxisModel(position_gain_per_s=gain, backlash_um=b_um)
    tr = simulate({"y": axis}, round_trip(0.0, travel, feed, dwell_s=0.1), rate_hz=500.0)
    gap_um = (tr.nut_mm["y"] - tr.table_true_mm["y"]) * 1e3
    assert np.all(np.abs(gap_um) <= b_um / 2 + 1e-6)
    assert np.all(np.isfinite(tr.table_mm["y"]))
    assert tr.table_true_mm["y"].max() <= travel + 1e-9  # a P loop never overshoots
