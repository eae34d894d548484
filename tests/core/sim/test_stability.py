"""No effect combination within the documented ranges blows up or keeps oscillating."""

import numpy as np
import pytest

from core.sim import (
    AxisModel,
    BacklashProfile,
    Compliance,
    CyclicError,
    Effects,
    Friction,
    SamplingSkew,
    ServoDynamics,
    Thermal,
    round_trip,
    simulate,
)
from core.sim.effects import REALISTIC_RANGES

DWELL_S = 4.0


def _draw(rng, category, name):
    lo, hi = REALISTIC_RANGES[category][name]
    return float(rng.choice([lo, hi, rng.uniform(lo, hi)]))  # corners often, inside sometimes


def _random_axis(rng):
    fx = {}
    on = rng.random(7) < 0.6
    mass = _draw(rng, "compliance", "table_mass_kg")
    if on[0] or on[1]:
        fx["compliance"] = Compliance(
            stiffness_n_per_um=_draw(rng, "compliance", "stiffness_n_per_um"),
            table_mass_kg=mass,
            damping_ratio=_draw(rng, "compliance", "damping_ratio"),
            guide_damping_n_s_per_mm=_draw(rng, "compliance", "guide_damping_n_s_per_mm"),
        )
    if on[1]:
        coulomb = max(_draw(rng, "friction", "coulomb_n"), 100.0, 0.02 * 9.81 * mass)
        fx["friction"] = Friction(
            coulomb_n=coulomb,
            static_n=coulomb * rng.choice([1.0, 1.3]),
            stribeck_velocity_mm_s=_draw(rng, "friction", "stribeck_velocity_mm_s"),
            viscous_n_s_per_mm=_draw(rng, "friction", "viscous_n_s_per_mm"),
            model=str(rng.choice(["stribeck", "lugre"])),
            bristle_stiffness_n_per_um=_draw(rng, "friction", "bristle_stiffness_n_per_um"),
            bristle_damping_ratio=_draw(rng, "friction", "bristle_damping_ratio"),
        )
    if on[2]:
        fx["thermal"] = Thermal(
            lead_error_um_per_m=_draw(rng, "thermal", "lead_error_um_per_m"),
            lead_growth_ppm_per_k=_draw(rng, "thermal", "lead_growth_ppm_per_k"),
            backlash_um_per_k=_draw(rng, "thermal", "backlash_um_per_k"),
        )
    if on[3]:
        fx["backlash_profile"] = BacklashProfile((0.0, 50.0, 100.0), tuple(rng.uniform(0.0, 300.0, 3)))
    if on[4]:
        fx["cyclic_error"] = CyclicError.of(
            (_draw(rng, "cyclic_error", "periods_mm"), _draw(rng, "cyclic_error", "amplitudes_um"), 0.0),
            (16.0, 5.0, 45.0),
        )
    if on[5]:
        fx["servo_dynamics"] = ServoDynamics(
            velocity_lag_s=_draw(rng, "servo_dynamics", "velocity_lag_s"),
            dead_time_s=_draw(rng, "servo_dynamics", "dead_time_s"),
        )
    if on[6]:
        fx["sampling_skew"] = SamplingSkew(_draw(rng, "sampling_skew", "table_delay_s"))
    return AxisModel(
        position_gain_per_s=float(rng.choice([10.0, 30.0, rng.uniform(10.0, 30.0)])),
        backlash_um=float(rng.choice([0.0, 300.0, rng.uniform(0.0, 300.0)])),
        effects=Effects(**fx),
    )


WORST = AxisModel(  # every effect at the edge that is hardest on stability
    position_gain_per_s=30.0,
    backlash_um=300.0,
    effects=Effects(
        compliance=Compliance(
            stiffness_n_per_um=100.0, table_mass_kg=1500.0, damping_ratio=0.2, guide_damping_n_s_per_mm=0.0
        ),
        friction=Friction(
            coulomb_n=0.02 * 9.81 * 1500.0, static_n=1.3 * 0.02 * 9.81 * 1500.0, stribeck_velocity_mm_s=0.1
        ),
        thermal=Thermal(lead_error_um_per_m=100.0, lead_growth_ppm_per_k=15.0, backlash_um_per_k=5.0),
        cyclic_error=CyclicError.of((0.5, 10.0, 0.0)),
        servo_dynamics=ServoDynamics(velocity_lag_s=0.01, dead_time_s=0.002),
        sampling_skew=SamplingSkew(0.005),
    ),
)


def _hunting_bound_um(axis):
    fr = axis.effects.friction
    if fr is None:
        return 0.5
    k = (axis.effects.compliance or Compliance()).stiffness_n_per_um
    return 2.0 * (fr.static_n - fr.coulomb_n) / k + 0.5


def _check_settles(axis, temperature_c):
    prog = round_trip(0.0, 100.0, 3000.0, acceleration_mm_s2=2000.0, dwell_s=DWELL_S)
    tr = simulate({"y": axis}, prog, temperature_c=temperature_c, rate_hz=500.0)
    t = tr.time_s
    err_um = (tr.command_mm["y"] - tr.table_true_mm["y"]) * 1e3
    assert np.all(np.isfinite(err_um))
    assert np.abs(err_um).max() < 3000.0 / 60.0 / axis.position_gain_per_s * 1e3 * 1.5 + 400.0  # lag v/K + b
    last = t > t[-1] - 1.0
    before = (t > t[-1] - 2.0) & ~last
    bound = _hunting_bound_um(axis)
    assert np.abs(err_um[last]).max() <= bound  # settled near the target ...
    assert np.abs(err_um[last]).max() <= np.abs(err_um[before]).max() + 1e-3  # ... not growing ...
    fr = axis.effects.friction
    if fr is None or fr.static_n == fr.coulomb_n:
        assert np.ptp(tr.table_true_mm["y"][last]) * 1e3 < 0.05  # ... and at rest when nothing can hunt


@pytest.mark.parametrize("seed", range(40))
def test_random_effect_combinations_settle_after_a_move(seed):
    rng = np.random.default_rng(seed)
    _check_settles(_random_axis(rng), temperature_c=float(rng.uniform(0.0, 40.0)))


@pytest.mark.parametrize("temperature_c", [0.0, 40.0])
def test_worst_corner_settles(temperature_c):
    _check_settles(WORST, temperature_c)
