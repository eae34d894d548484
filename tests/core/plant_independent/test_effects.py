"""Each effect of the independent plant changes the data in its own physical way."""

import numpy as np
import pytest

from core.plant_independent.drive import DriveParams, internal_step_s
from core.plant_independent.effects import EFFECTS, draw_effect, draw_nominal, drive_params

from .helpers import B_UM, K_A_MM_PER_REV, K_PER_S, circle, nominal, round_trip
from .test_nominal import _steady


def _deflection_um(t, cmd, u, x, sign):
    idx, v = _steady(t, cmd, sign)
    return sign * np.mean(u[idx] - x[idx]) * 1e3, v


def test_feed_forward_reduces_the_steady_lag_to_one_minus_kff():
    eff = {"servo_dynamics": {"ff_fraction": 0.6, "gain_ratio": 1.0, "vloop_bandwidth_hz": 50.0,
                              "vloop_damping": 0.7, "feedback_delay_s": 0.5e-3}}  # fmt: skip
    t, cmd, u, x = round_trip(nominal(), eff)
    idx, v = _steady(t, cmd, 1)
    lag = cmd[idx] - x[idx]
    # K (c - x(t - T)) + k_ff v = v with x(t - T) = x - v T
    assert np.allclose(lag, 0.4 * v / K_PER_S - v * 0.5e-3, rtol=0.01)
    t0, cmd0, _, x0 = round_trip(nominal())
    assert np.mean(lag) < 0.45 * np.mean((cmd0 - x0)[idx])


def test_gain_ratio_and_feedback_dead_time_set_the_steady_lag():
    eff = {"servo_dynamics": {"ff_fraction": 0.0, "gain_ratio": 1.3, "vloop_bandwidth_hz": 40.0,
                              "vloop_damping": 0.6, "feedback_delay_s": 3e-3}}  # fmt: skip
    t, cmd, u, x = round_trip(nominal(), eff)
    idx, v = _steady(t, cmd, 1)
    # the loop sees the table 3 ms late, i.e. v*T further back, and closes that too
    assert np.allclose(cmd[idx] - x[idx], v / (1.3 * K_PER_S) - v * 3e-3, rtol=0.01)


def test_feedback_dead_time_and_velocity_loop_enlarge_the_circle_against_the_p_loop():
    """A delay in the loop lowers its phase margin: the closed loop's gain near w rises above the
    P loop's, so the radius loss shrinks (and the start-up overshoots)."""
    noms = {a: nominal(position_gain_per_s=30.0, backlash_um=20.0) for a in ("x", "y")}
    slow = {"ff_fraction": 0.0, "gain_ratio": 1.0, "vloop_bandwidth_hz": 30.0, "vloop_damping": 0.5,
            "feedback_delay_s": 3e-3}  # fmt: skip
    r_loss = []
    for eff in ({a: {} for a in ("x", "y")}, {a: {"servo_dynamics": slow} for a in ("x", "y")}):
        t, t_data, cols = circle(noms, eff, radius=20.0, feed=3000.0)
        r = np.hypot(cols["x_table_mm"] - 400.0, cols["y_table_mm"] - 400.0) - 20.0
        r_loss.append(np.median(r[t > t_data + 0.5]) * 1e3)
    assert r_loss[1] > r_loss[0] + 5.0, r_loss


def test_karnopp_stick_slip_breaks_away_at_the_static_force_and_slides_at_the_coulomb_force():
    m, k, fc, fs = 800.0, 100.0, 1500.0, 4500.0
    eff = {"friction": {"form": "karnopp", "table_mass_kg": m, "chain_stiffness_n_per_um": k,
                        "chain_damping_ratio": 0.1, "coulomb_n": fc, "static_n": fs}}  # fmt: skip
    t, cmd, u, x = round_trip(nominal(), eff, feed=3000.0, acc=300.0)
    d_slide, _ = _deflection_um(t, cmd, u, x, 1)
    assert abs(d_slide - (B_UM / 2 + fc / k)) < 0.05 * (fc / k)
    # below the critical speed (F_s - F_c) / sqrt(k m) = 10.6 mm/s the stroke stick-slips throughout
    t2, cmd2, u2, x2 = round_trip(nominal(), eff, feed=480.0, acc=300.0)
    idx, _ = _steady(t2, cmd2, 1)
    assert np.ptp(u2[idx] - x2[idx]) * 1e3 > (fs - fc) / k
    # break-away: the table stands still while the nut winds the chain up to F_s
    moving = np.flatnonzero(np.abs(x - x[0]) > 1e-3)[0]
    wind_um = (u[moving] - u[0]) * 1e3
    assert wind_um > 0.9 * fs / k  # the nut travelled across the gap and stretched the chain to F_s
    assert np.max(u[: moving + 200] - x[: moving + 200]) * 1e3 > B_UM / 2 + 0.9 * fs / k
    # and the slip then overshoots: the chain relaxes towards the Coulomb deflection
    assert np.min((u - x)[moving : moving + 2000]) * 1e3 < B_UM / 2 + 1.2 * fc / k


def test_dahl_friction_deflects_the_chain_by_coulomb_over_k_without_sticking():
    m, k, fc = 800.0, 100.0, 1500.0
    eff = {"friction": {"form": "dahl", "table_mass_kg": m, "chain_stiffness_n_per_um": k,
                        "chain_damping_ratio": 0.1, "coulomb_n": fc, "presliding_um": 3.0}}  # fmt: skip
    t, cmd, u, x = round_trip(nominal(), eff, feed=600.0, acc=300.0)
    d_slide, _ = _deflection_um(t, cmd, u, x, 1)
    assert abs(d_slide - (B_UM / 2 + fc / k)) < 0.05 * (fc / k)
    idx, _ = _steady(t, cmd, 1)
    assert np.ptp(u[idx] - x[idx]) * 1e3 < 0.1  # slides smoothly even at 10 mm/s
    # pre-sliding: the table creeps before the chain carries the full Coulomb force
    moving = np.flatnonzero(np.abs(x - x[0]) > 1e-3)[0]
    assert (u[moving] - u[0]) * 1e3 < B_UM + fc / k


def test_compliance_deflects_the_chain_with_the_drive_force():
    m, k, fg = 1200.0, 80.0, 300.0
    eff = {"compliance": {"table_mass_kg": m, "chain_stiffness_n_per_um": k, "chain_damping_ratio": 0.15,
                          "guide_friction_n": fg}}  # fmt: skip
    t, cmd, u, x = round_trip(nominal(), eff, feed=6000.0, acc=600.0, jerk_s=0.008)
    d_slide, v = _deflection_um(t, cmd, u, x, 1)
    oil_n = m / 2.0 * v * 1e-3  # the guide's viscous damper, c_g = m / 2 s
    assert abs(d_slide - (B_UM / 2 + (fg + oil_n) / k)) < 0.05
    # mid-acceleration of the first stroke: the chain carries m*a + F_g
    a = np.gradient(np.gradient(cmd, t), t)
    acc_idx = np.flatnonzero(np.abs(a - 600.0) < 1.0)
    acc_idx = acc_idx[acc_idx < len(t) // 4]
    acc_idx = acc_idx[acc_idx > (acc_idx[0] + acc_idx[-1]) // 2]  # the later half: the chain's ringing has decayed
    assert len(acc_idx) > 20
    d_acc = np.mean(u[acc_idx] - x[acc_idx]) * 1e3
    # the table's own acceleration there (the P loop still lags the command's)
    a_table = 2.0 * np.polyfit(t[acc_idx], x[acc_idx], 2)[0] * 1e-3  # m/s^2
    assert 0.3 < a_table < 0.6
    oil_n = m / 2.0 * np.mean(np.gradient(x, t)[acc_idx]) * 1e-3
    assert abs(d_acc - (B_UM / 2 + (fg + oil_n + m * a_table) / k)) < 0.05 * (m * a_table / k), d_acc


def _lead_scale(t, cmd, u, x):
    idx, _ = _steady(t, cmd, 1)
    return np.polyfit(u[idx], x[idx], 1)[0]


def test_thermal_growth_changes_the_measured_lead_and_the_backlash_with_temperature():
    th = {"lead_growth_ppm_per_k": 11.0, "bearing_mm": 250.0, "bearing_shift_mm_per_k": 5.0,
          "backlash_pct_per_k": 1.0}  # fmt: skip
    scales, bs = {}, {}
    for temp in (10.0, 30.0):
        t, cmd, u, x = round_trip(nominal(), {"thermal": th}, start=50.0, end=700.0, feed=3000.0, temp=temp)
        scales[temp] = _lead_scale(t, cmd, u, x)
        out, _ = _steady(t, cmd, 1)
        back, _ = _steady(t, cmd, -1)
        # backlash at one position: compare the passes where both are at the same motor travel
        bs[temp] = (np.interp(375.0, x[back][::-1], (x - u)[back][::-1]) - np.interp(375.0, x[out], (x - u)[out])) * 1e3
    assert np.isclose(scales[30.0] - scales[10.0], 11e-6 * 20.0, rtol=0.02)
    assert np.isclose(bs[30.0] / bs[10.0], 1.1 / 0.9, rtol=0.01)


def test_wear_bumps_widen_the_backlash_where_they_sit():
    bp = {"bumps": [{"shape": "gauss", "centre_mm": 200.0, "width_mm": 30.0, "amplitude": 0.5},
                    {"shape": "cosine", "centre_mm": 500.0, "width_mm": 60.0, "amplitude": 0.3}]}  # fmt: skip
    t, cmd, u, x = round_trip(nominal(), {"backlash_profile": bp}, start=50.0, end=700.0, feed=3000.0)
    out, _ = _steady(t, cmd, 1)
    back, _ = _steady(t, cmd, -1)

    def b_at(pos):
        return (np.interp(pos, x[back][::-1], (x - u)[back][::-1]) - np.interp(pos, x[out], (x - u)[out])) * 1e3

    assert np.isclose(b_at(200.0), 1.5 * B_UM, rtol=0.02)
    assert np.isclose(b_at(500.0), 1.3 * B_UM, rtol=0.02)
    assert np.isclose(b_at(350.0), B_UM, rtol=0.02)


def test_cyclic_error_has_the_gear_period_not_the_lead_or_k_a():
    period = K_A_MM_PER_REV * 2.3
    cy = {"period_mm": period, "amplitude_um": 4.0, "phase_rad": 0.3, "lead_amplitude_um": 0.0, "lead_phase_rad": 0.0}
    t, cmd, u, x = round_trip(nominal(), {"cyclic_error": cy}, start=100.0, end=500.0, feed=3000.0)
    idx, _ = _steady(t, cmd, 1)
    r = (x[idx] - u[idx]) * 1e3
    r = r - np.polyval(np.polyfit(x[idx], r, 1), x[idx])
    grid = np.linspace(x[idx][0], x[idx][-1], 8192)
    spec = np.abs(np.fft.rfft(np.interp(grid, x[idx], r)))
    f = np.fft.rfftfreq(grid.size, grid[1] - grid[0])
    peak_period = 1.0 / f[1 + np.argmax(spec[1:])]
    assert abs(peak_period - period) < 0.03 * period
    assert abs(np.std(r) * np.sqrt(2) - 4.0) < 0.2


def test_sampling_skew_makes_an_apparent_backlash_that_grows_with_feed_and_drifts():
    skew = {"table_delay_s": 3e-3, "drift_fraction": 0.0, "jitter_fraction": 0.0}
    apparent = {}
    for feed in (1200.0, 3000.0):
        t, cmd, u, x = round_trip(nominal(), None, feed=feed, skew=skew)
        out, v = _steady(t, cmd, 1)
        back, _ = _steady(t, cmd, -1)
        apparent[feed] = (np.mean((x - u)[back]) - np.mean((x - u)[out])) * 1e3
    dv_mm_s = (3000.0 - 1200.0) / 60.0
    # a table latched late reads ahead of the motor in either direction: the apparent backlash shrinks
    assert np.isclose(apparent[3000.0] - apparent[1200.0], -2 * 3e-3 * dv_mm_s * 1e3, rtol=0.02)
    # a drifting delay: the table-minus-motor offset of one stroke changes along it
    drift = {"table_delay_s": 3e-3, "drift_fraction": 0.5, "jitter_fraction": 0.0}
    t, cmd, u, x = round_trip(nominal(), None, feed=3000.0, skew=drift)
    out, v = _steady(t, cmd, 1)
    d = (x - u)[out] * 1e3
    slope_um_per_s = np.polyfit(t[out], d, 1)[0]
    expected = v * 3e-3 * 0.5 * 2 / t[-1] * 1e3  # d(tau)/dt * v
    assert np.isclose(slope_um_per_s, expected, rtol=0.05)


@pytest.mark.parametrize("label", EFFECTS)
def test_drawn_parameters_lie_in_the_documented_ranges_and_give_a_stable_step(label):
    rng = np.random.default_rng(7)
    for _ in range(50):
        nom = draw_nominal(rng)
        assert 8.0 <= nom["position_gain_per_s"] <= 40.0 and 15.0 <= nom["backlash_um"] <= 150.0
        eff = draw_effect(label, rng, nom)
        p = drive_params(nom, {} if label == "sampling_skew" else {label: eff})
        assert isinstance(p, DriveParams)
        h = internal_step_s(p)
        assert 1e-3 / h == pytest.approx(round(1e-3 / h))  # divides the IPO cycle
        if p.mass_mode:
            omega = np.sqrt(p.chain_stiffness_n_per_um * 1e6 / p.table_mass_kg)
            assert omega * h <= 0.2 + 1e-9
            assert p.gain_per_s / (2 * p.chain_damping_ratio * omega) <= 0.5 + 1e-9
        if label == "cyclic_error":
            ratio = eff["period_mm"] / nom["transmission_mm_per_rev"]
            assert 1.3 <= ratio <= 3.7 and not np.isclose(eff["period_mm"], nom["screw_lead_mm"])
        if label == "thermal":
            assert 100.0 <= eff["bearing_mm"] <= 400.0
        if label == "backlash_profile":
            assert 2 <= len(eff["bumps"]) <= 4
