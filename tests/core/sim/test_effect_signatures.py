"""Each effect leaves the signature the gap diagnosis looks for."""

import numpy as np
import pytest

from core.errors import InputError
from core.sim import (
    AxisModel,
    BacklashProfile,
    Compliance,
    CyclicError,
    Effects,
    Encoders,
    Friction,
    SamplingSkew,
    ServoDynamics,
    Thermal,
    circle,
    round_trip,
    simulate,
)
from tests.core.sim.helpers import apparent_backlash_um, strokes

B_UM = 60.0


def _rt(effects=None, *, feed=1000.0, acc=500.0, travel=(0.0, 120.0), temp=20.0, rate=1000.0, **axis_kw):
    axis = AxisModel(backlash_um=B_UM, effects=effects or Effects(), **axis_kw)
    prog = round_trip(*travel, feed, acceleration_mm_s2=acc, dwell_s=0.5)
    return simulate({"y": axis}, prog, temperature_c=temp, rate_hz=rate)


@pytest.mark.parametrize("model", ["stribeck", "lugre"])
def test_friction_adds_lost_motion_of_twice_the_friction_over_stiffness(model):
    fr = Friction(coulomb_n=400.0, static_n=400.0, viscous_n_s_per_mm=3.0, model=model)
    ch = Compliance(stiffness_n_per_um=100.0)
    tr = _rt(Effects(friction=fr, compliance=ch))
    force_n = 400.0 + 3.0 * 1000.0 / 60.0 + ch.guide_damping_n_s_per_mm * 1000.0 / 60.0
    expected = B_UM + 2 * force_n / ch.stiffness_n_per_um
    assert apparent_backlash_um(tr, "y", 20.0, 100.0) == pytest.approx(expected, abs=0.05)


@pytest.mark.parametrize("model", ["stribeck", "lugre"])
@pytest.mark.parametrize("asym", [0.25, -0.25])
def test_friction_that_differs_by_direction_moves_the_table_by_half_the_difference_over_stiffness(model, asym):
    """F+ = 400 (1 + a) N one way, F- = 400 (1 - a) N the other, on 100 N/µm: the lost
    motion is that of the mean friction, and while it moves the table sits
    (F- - F+) / 2k = -a 400 / 100 µm from where the same mean friction both ways puts it."""
    ch = Compliance(stiffness_n_per_um=100.0)

    def offsets_um(a):
        tr = _rt(Effects(friction=Friction(coulomb_n=400.0, model=model, direction_asymmetry=a), compliance=ch))
        (_, o_out), (_, o_back) = strokes(tr, "y", 20.0, 100.0)
        return apparent_backlash_um(tr, "y", 20.0, 100.0), 0.5e3 * (np.mean(o_out) + np.mean(o_back))

    width, centre = offsets_um(asym)
    width_0, centre_0 = offsets_um(0.0)
    assert width == pytest.approx(width_0, abs=0.05)
    assert centre - centre_0 == pytest.approx(-asym * 400.0 / 100.0, abs=0.05)


def test_friction_sticks_then_slips_after_a_reversal():
    nominal = _rt(travel=(0.0, 20.0), rate=50000.0)
    fric = Friction(coulomb_n=500.0, static_n=650.0, stribeck_velocity_mm_s=1.0)
    fr = _rt(Effects(friction=fric), travel=(0.0, 20.0), rate=50000.0)
    t = fr.time_s
    cmd = fr.command_mm["y"]
    t_rev = t[np.flatnonzero(cmd >= cmd.max() - 1e-12)[-1]]  # the return stroke starts
    window = (t > t_rev) & (t < t_rev + 1.5)

    def lost_motion_um(tr):  # nut travel back before the table has come back 1 µm
        y = tr.table_true_mm["y"][window]
        i = np.argmax(y < y[0] - 1e-3)
        nut = tr.nut_mm["y"][window]
        return (nut[: i + 1].max() - nut[i]) * 1e3, t[window][i]

    lost_nominal, _ = lost_motion_um(nominal)
    lost_friction, t_slip = lost_motion_um(fr)
    assert lost_nominal == pytest.approx(B_UM + 1.0, abs=0.7)  # up to two samples of nut travel
    # stick: the nut must also wind the chain up to the static friction (extra lost motion) ...
    assert lost_friction - lost_nominal > 0.8 * fric.static_n / 200.0
    # ... then slip: the chain force drops from the static to the sliding friction level.
    k_n_per_um = 200.0  # the default chain, compliance being off
    deflection_um = (np.abs(fr.nut_mm["y"] - fr.table_true_mm["y"]) * 1e3 - B_UM / 2)[window]
    tw = t[window]
    assert deflection_um[tw < t_slip + 0.01].max() > 0.95 * fric.static_n / k_n_per_um
    sliding = deflection_um[np.argmax(tw > t_slip + 0.3)]
    v_back = np.abs(np.gradient(fr.table_true_mm["y"], t))[window][np.argmax(tw > t_slip + 0.3)]
    assert sliding == pytest.approx((fric.coulomb_n + 1.0 * v_back) / k_n_per_um, rel=0.02)


def test_compliance_lag_grows_with_acceleration():
    ch = Compliance(stiffness_n_per_um=100.0, table_mass_kg=1000.0, damping_ratio=0.3)
    peaks = []
    for acc in (100.0, 200.0):
        tr = _rt(Effects(compliance=ch), acc=acc)
        t = tr.time_s
        first = (t > 0.6) & (t < t[np.argmax(tr.command_mm["y"])])  # the out stroke, nut pushing
        a_table = np.gradient(np.gradient(tr.table_true_mm["y"], t), t)
        deflection_um = (tr.nut_mm["y"] - tr.table_true_mm["y"]) * 1e3 - B_UM / 2
        slope, _ = np.polyfit(a_table[first], deflection_um[first], 1)
        assert slope == pytest.approx(ch.table_mass_kg / ch.stiffness_n_per_um * 1e-3, rel=0.05)  # m a / k
        peaks.append(deflection_um[first].max() - np.median(deflection_um[first]))
    # the loop smooths the ramp, so the table's peak acceleration (and lag) grows less than 2x
    assert peaks[1] > peaks[0] + 0.1


def test_thermal_shifts_lead_and_backlash_with_temperature():
    th = Thermal(lead_error_um_per_m=-20.0, lead_growth_ppm_per_k=2.0, backlash_um_per_k=3.0)
    fx = Effects(thermal=th)
    cold, warm = _rt(fx, temp=10.0), _rt(fx, temp=30.0)
    assert apparent_backlash_um(warm, "y", 10.0, 110.0) - apparent_backlash_um(cold, "y", 10.0, 110.0) == (
        pytest.approx(3.0 * 20.0, abs=1e-3)
    )
    for tr, temp in ((cold, 10.0), (warm, 30.0)):
        (pos, off), _ = strokes(tr, "y", 10.0, 110.0)
        slope_um_per_m = np.polyfit(pos, off, 1)[0] * 1e6
        assert slope_um_per_m == pytest.approx(-20.0 + 2.0 * (temp - 20.0), abs=0.01)


def test_backlash_profile_is_measured_where_it_is():
    prof = BacklashProfile(positions_mm=(0.0, 120.0), widths_um=(40.0, 100.0))
    tr = _rt(Effects(backlash_profile=prof))
    assert apparent_backlash_um(tr, "y", 18.0, 22.0) == pytest.approx(50.0, abs=0.2)
    assert apparent_backlash_um(tr, "y", 98.0, 102.0) == pytest.approx(90.0, abs=0.2)


def test_cyclic_error_appears_with_its_period_and_amplitude():
    ce = CyclicError.of((16.0, 3.0, 30.0), (6.857, 1.5, 0.0))
    tr = _rt(Effects(cyclic_error=ce))
    (pos, off), _ = strokes(tr, "y", 10.0, 110.0)
    cols = [np.ones_like(pos)]
    for p in (16.0, 6.857):
        cols += [np.sin(2 * np.pi * pos / p), np.cos(2 * np.pi * pos / p)]
    coef = np.linalg.lstsq(np.column_stack(cols), off * 1e3, rcond=None)[0]
    assert np.hypot(coef[1], coef[2]) == pytest.approx(3.0, abs=0.01)
    assert np.degrees(np.arctan2(coef[2], coef[1])) == pytest.approx(30.0, abs=0.5)
    assert np.hypot(coef[3], coef[4]) == pytest.approx(1.5, abs=0.01)


def test_a_scale_interpolation_error_is_in_the_table_reading_alone():
    """``on="scale"``: the recorded table carries the error at the true table position;
    the nut and the true table move as without it (the loop follows the true table), and
    a period of 20 µm with 2 µm (slope 0.63, past the nut's limit) is a valid reading error."""
    ce = CyclicError.of((0.020, 2.0, 30.0), on="scale")
    plain, scaled = _rt(), _rt(Effects(cyclic_error=ce))
    assert np.array_equal(plain.nut_mm["y"], scaled.nut_mm["y"])
    assert np.array_equal(plain.table_true_mm["y"], scaled.table_true_mm["y"])
    x = scaled.table_true_mm["y"]
    expected = x + 2e-3 * np.sin(2 * np.pi * x / 0.020 + np.radians(30.0))
    assert np.max(np.abs(scaled.table_mm["y"] - expected)) < 1e-9
    with pytest.raises(InputError, match="run backwards"):
        CyclicError.of((0.020, 2.0, 30.0))  # the same on the nut would stall it
    with pytest.raises(InputError, match="'nut' or 'scale'"):
        CyclicError.of((16.0, 2.0, 0.0), on="motor")


def _roundness_terms_um(x_effects, y_effects, feed=3000.0, radius=10.0):
    axes = {"x": AxisModel("x", effects=x_effects), "y": AxisModel("y", effects=y_effects)}
    tr = simulate(axes, circle(radius, feed_mm_min=feed, sweep_deg=360.0), rate_hz=500.0)
    x, y = tr.table_true_mm["x"], tr.table_true_mm["y"]
    th = np.arctan2(y, x)
    design = np.column_stack([np.ones_like(th), np.cos(2 * th), np.sin(2 * th)])
    return np.linalg.lstsq(design, np.hypot(x, y) * 1e3 - radius * 1e3, rcond=None)[0]


def test_unequal_servo_dynamics_tilt_the_circle_into_a_45_degree_ellipse():
    lag = Effects(servo_dynamics=ServoDynamics(velocity_lag_s=0.008, dead_time_s=0.001))
    _, c_eq, s_eq = _roundness_terms_um(lag, lag)
    _, c_un, s_un = _roundness_terms_um(lag, Effects())
    assert abs(s_eq) < 0.01 and abs(c_eq) < 0.01  # equal axes: round (radius change only)
    assert abs(s_un) > 5.0  # unequal axes: an ellipse with axes at +-45 deg


def test_servo_dynamics_change_the_radius_more_at_higher_feed():
    lag = Effects(servo_dynamics=ServoDynamics(velocity_lag_s=0.008, dead_time_s=0.001))
    change = []
    for feed in (1000.0, 3000.0):
        r_lag = _roundness_terms_um(lag, lag, feed)[0]
        r_nom = _roundness_terms_um(Effects(), Effects(), feed)[0]
        change.append(abs(r_lag - r_nom))
    assert 0.05 < change[0] < change[1] / 3


@pytest.mark.parametrize("delay_s", [0.002, -0.001])
def test_sampling_skew_changes_apparent_backlash_in_proportion_to_feed(delay_s):
    fx = Effects(sampling_skew=SamplingSkew(table_delay_s=delay_s))
    for feed in (600.0, 2400.0):
        tr = _rt(fx, feed=feed)
        # the later table sample runs ahead by v*delay on both strokes, closing the gap by 2 v delay
        expected = B_UM - 2 * feed / 60.0 * delay_s * 1e3
        assert apparent_backlash_um(tr, "y", 20.0, 100.0) == pytest.approx(expected, abs=0.01)
        assert np.abs(tr.table_true_mm["y"] - tr.table_mm["y"]).max() > 0  # only the samples move


def test_encoders_quantise_and_add_reproducible_noise():
    enc = Encoders(motor_counts_per_rev=2**12, table_resolution_um=0.5)
    tr = _rt(encoders=enc)
    counts = tr.motor_rev["y"] * 2**12
    assert counts == pytest.approx(np.round(counts), abs=1e-6)
    steps = tr.table_mm["y"] * 2e3
    assert steps == pytest.approx(np.round(steps), abs=1e-6)
    noisy = Encoders(motor_noise_um=0.3, table_noise_um=0.2)
    rng_runs = [
        simulate(
            {"y": AxisModel(backlash_um=B_UM, encoders=noisy)},
            round_trip(0.0, 20.0, 1000.0),
            rng=np.random.default_rng(7),
        )
        for _ in range(2)
    ]
    a, b = rng_runs
    assert np.array_equal(a.table_mm["y"], b.table_mm["y"])
    assert np.std((a.table_mm["y"] - a.table_true_mm["y"]) * 1e3) == pytest.approx(0.2, rel=0.05)
    ka = a.models["y"].transmission_mm_per_rev
    assert np.std((a.motor_rev["y"] - a.motor_true_rev["y"]) * ka * 1e3) == pytest.approx(0.3, rel=0.05)


def test_a_stick_band_keeps_a_chain_stick_slipping_at_speeds_where_it_would_slide():
    """Karnopp's zero-velocity band (Friction.stick_band_mm_s): a table slower than the band
    counts as at rest, so a slowing table is caught before its velocity crosses zero and
    stick-slip persists to higher drive speeds; without a band (0, the default) the same
    chain slides steadily there. Measured: the spread of the chain's stretch over the
    second half of the constant-speed stroke out."""

    def spread_um(band, feed):
        fr = Friction(coulomb_n=1000.0, static_n=2500.0, stribeck_velocity_mm_s=0.1, stick_band_mm_s=band)
        ch = Compliance(stiffness_n_per_um=100.0, table_mass_kg=800.0, damping_ratio=0.1)
        axis = AxisModel(backlash_um=B_UM, effects=Effects(compliance=ch, friction=fr))
        tr = simulate({"y": axis}, round_trip(0.0, 60.0, feed, acceleration_mm_s2=500.0, dwell_s=0.5),
                      temperature_c=20.0, rate_hz=2000.0)  # fmt: skip
        v = np.gradient(tr.command_mm["y"], tr.time_s)
        out = np.flatnonzero(np.abs(v - v.max()) < 1e-6 * v.max())
        d = (tr.table_true_mm["y"] - tr.nut_mm["y"])[out[out.size // 2 :]] * 1e3
        return float(np.ptp(d))

    slip_um = 2 * (2500.0 - 1000.0) / 100.0  # the stretch swing of a full stick-slip cycle, about
    assert spread_um(0.0, 600.0) < 0.1
    assert spread_um(2.0, 600.0) > slip_um
    # well below either onset both stick-slip alike
    assert spread_um(2.0, 200.0) == pytest.approx(spread_um(0.0, 200.0), rel=0.05)
    with pytest.raises(InputError):
        Friction(coulomb_n=100.0, stick_band_mm_s=-1.0)
    with pytest.raises(InputError, match="stribeck"):
        Friction(coulomb_n=100.0, model="lugre", stick_band_mm_s=1.0)
