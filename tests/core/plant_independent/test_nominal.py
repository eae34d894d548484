"""The nominal plant (no effect, zero noise) against the closed forms of a P loop with backlash."""

import numpy as np

from core.plant_independent.program import circle_program

from .helpers import B_UM, K_PER_S, circle, nominal, round_trip


def _steady(t, cmd, sign):
    """Samples in the constant-feed part of the stroke in direction ``sign``, 0.6 s after the ramp."""
    v = np.gradient(cmd, t)
    vmax = np.max(sign * v)
    at_feed = sign * v > 0.999 * vmax
    idx = np.flatnonzero(at_feed)
    first, last = idx[0], idx[-1]
    idx = idx[(t[idx] > t[first] + 0.6) & (t[idx] < t[last] - 0.05) & (idx < len(t) // 2 if sign > 0 else idx > len(t) // 2)]
    return idx, vmax


def test_round_trip_table_lags_the_command_by_feed_over_k():
    t, cmd, u, x = round_trip(nominal())
    for sign in (1, -1):
        idx, v = _steady(t, cmd, sign)
        lag = sign * (cmd[idx] - x[idx])
        assert len(idx) > 1000
        assert np.allclose(lag, v / K_PER_S, rtol=0.01), (lag.min(), lag.max(), v / K_PER_S)


def test_table_minus_nut_switches_by_the_backlash_at_reversals():
    t, cmd, u, x = round_trip(nominal())
    out, _ = _steady(t, cmd, 1)
    back, _ = _steady(t, cmd, -1)
    d_out = np.mean(x[out] - u[out])
    d_back = np.mean(x[back] - u[back])
    assert abs((d_back - d_out) * 1e3 - B_UM) < 0.01 * B_UM
    # at rest between the strokes the table stays where the last flank left it
    assert np.std(x[out] - u[out]) * 1e3 < 0.1


def test_circle_steady_radial_error_is_the_first_order_p_loop_formula():
    k = 10.0
    noms = {a: nominal(position_gain_per_s=k, backlash_um=20.0) for a in ("x", "y")}
    radius, feed = 50.0, 3000.0
    t, t_data, cols = circle(noms, radius=radius, feed=feed)
    w = feed / 60.0 / radius
    expected_um = radius * (1.0 / np.sqrt(1.0 + (w / k) ** 2) - 1.0) * 1e3
    dx, dy = cols["x_table_mm"] - 400.0, cols["y_table_mm"] - 400.0
    r_um = (np.hypot(dx, dy) - radius) * 1e3
    # on the data arc, away from the backlash crossings of either axis (whose transients decay with 1/K)
    ang = np.arctan2(cols["y_command_mm"] - 400.0, cols["x_command_mm"] - 400.0)
    mask = (t > t_data) & (np.abs(np.cos(ang)) > 0.5) & (np.abs(np.sin(ang)) > 0.5)
    v = np.hypot(np.gradient(cols["x_command_mm"], t), np.gradient(cols["y_command_mm"], t))
    mask &= v > 0.999 * feed / 60.0
    assert mask.sum() > 100
    assert expected_um < -200.0  # a clear radius loss at these conditions
    assert np.allclose(r_um[mask], expected_um, rtol=0.02), (r_um[mask].min(), r_um[mask].max(), expected_um)


def test_circle_program_starts_at_rest_on_the_feed_in_arc_and_reaches_the_data_arc_at_its_start_angle():
    for lead_in in (0.0, 90.0, 180.0):
        prog, t_data = circle_program(("x", "y"), 40.0, (0.0, 0.0), 2000.0, 800.0, "cw", 30.0, 360.0, lead_in, 45.0,
                                      0.01)  # fmt: skip
        x, y = prog.command_mm["x"], prog.command_mm["y"]
        a0 = np.rad2deg(np.arctan2(y[0], x[0]))
        assert np.isclose((a0 - (30.0 + lead_in) + 180.0) % 360.0 - 180.0, 0.0, atol=1e-6)  # cw: feed-in from above
        i = int(round(t_data / 1e-3))
        assert np.isclose(np.rad2deg(np.arctan2(y[i], x[i])), 30.0, atol=0.5)
        assert np.hypot(x[1] - x[0], y[1] - y[0]) == 0.0  # at rest at the start
        end = np.rad2deg(np.arctan2(y[-1], x[-1]))
        assert np.isclose((end - (30.0 - 360.0 - 45.0) + 180.0) % 360.0 - 180.0, 0.0, atol=1e-6)
