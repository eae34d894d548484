"""The given-motor models against the simulator they stand in for."""

import numpy as np
from hypothesis import given
from hypothesis import strategies as st

from core.gap.data import prepare_round_trip
from core.gap.play import play, play_dahl, play_inertia
from core.gap.roundtrip import nominal_model, predict_nominal, residual_um
from core.sim import AxisModel, Compliance, Effects, round_trip, simulate


@given(st.lists(st.floats(-5, 5), min_size=2, max_size=200), st.floats(0.0, 0.5))
def test_play_stays_within_the_backlash_and_only_moves_when_pushed(steps, hb):
    u = np.cumsum(steps)
    x = play(u, np.full(u.size, hb), u[0])
    assert np.all(x >= u - hb - 1e-12) and np.all(x <= u + hb + 1e-12)
    moved = np.flatnonzero(np.diff(x) != 0) + 1
    assert np.all(np.isclose(np.abs(x[moved] - u[moved]), hb))  # moves only when a flank pushes


def test_given_motor_play_reproduces_the_nominal_simulator_exactly():
    axis = AxisModel(name="y", backlash_um=80.0)
    tr = simulate({"y": axis}, round_trip(10.0, 90.0, 1200.0, 500.0, 0.5), rate_hz=500.0)
    run = prepare_round_trip(tr.to_run("rt.csv"), axis.to_axis_spec((0.0, 100.0)), "train")
    r = residual_um(predict_nominal(np.array([80.0]), run), run)
    assert np.max(np.abs(r)) < 0.01  # µm: the rigid chain is the play operator of Eq. 5
    r_wrong = residual_um(predict_nominal(np.array([70.0]), run), run)
    assert np.max(np.abs(r_wrong)) > 4.0
    assert nominal_model(80.0).n_extra == 0


def _out_and_back(n_per_mm: int) -> np.ndarray:
    """The nut 1 mm out and back, and out again, ``n_per_mm`` samples per mm."""
    out = np.linspace(0.0, 1.0, n_per_mm + 1)
    return np.concatenate([out, out[::-1][1:], out[1:]])


def test_dahl_play_springs_back_by_the_presliding_length_times_ln2_and_then_lags_as_play():
    """After steady sliding the chain unloads in the gap and the table springs back by
    l_p ln 2 (its friction falling from F_c to zero, Dahl's law integrated); once sliding
    on the other flank it lags the nut by b/2 + L, as a play of the apparent backlash."""
    u = _out_and_back(1000)
    hb, lc, lp = 0.03, 0.0025, 0.005
    x = play_dahl(u, np.full(u.size, hb), lc, lp, -hb - lc)
    xp = play(u, np.full(u.size, hb + lc), -hb - lc)
    back = (x - xp)[1001:1040] * 1e3  # within the gap after the first reversal (60 µm + 5 µm of nut travel)
    assert np.min(back) < 0 and abs(np.min(back) + lp * np.log(2) * 1e3) < 0.01
    for i in (500, 1500, 2500):  # sliding: the play of the apparent backlash
        assert abs(x[i] - xp[i]) < 1e-9


def test_dahl_play_without_presliding_is_the_play_of_the_apparent_backlash_and_is_rate_independent():
    hb, lc = 0.03, 0.0025
    u = _out_and_back(1000)
    x0 = play_dahl(u, np.full(u.size, hb), lc, 1e-7, -hb - lc)
    assert np.max(np.abs(x0 - play(u, np.full(u.size, hb + lc), -hb - lc))) < 1e-6  # mm
    # each sample is solved exactly: a 10x coarser sampling gives the same table where both sample
    fine = play_dahl(u, np.full(u.size, hb), lc, 0.005, -hb - lc)
    uc = _out_and_back(100)
    coarse = play_dahl(uc, np.full(uc.size, hb), lc, 0.005, -hb - lc)
    assert np.max(np.abs(fine[::10] - coarse)) < 1e-9


def test_inertia_model_lags_by_friction_and_damping_over_stiffness_at_constant_speed():
    t = np.arange(0.0, 3.0, 1e-3)
    u = np.where(t < 1.0, 0.0, 25.0 * (t - 1.0))
    w, mu, cg = 400.0, 200.0, 8.0
    x = play_inertia(u, np.gradient(u, t), t, np.full(t.size, 0.05), w * w, 0.4 * w, cg, mu, 10, -0.05)
    expected_um = -50.0 - (mu + cg * 25.0) / w**2 * 1e3
    assert abs((x[-1] - u[-1]) * 1e3 - expected_um) < 0.05


def test_compliance_model_recovers_the_simulated_natural_frequency():
    from core.gap.candidates import compliance_stage, compose
    from core.gap.roundtrip import fit

    comp = Compliance(stiffness_n_per_um=150.0, table_mass_kg=1200.0, damping_ratio=0.3, guide_damping_n_s_per_mm=5.0)
    axis = AxisModel(name="y", backlash_um=60.0, effects=Effects(compliance=comp))
    spec = axis.to_axis_spec((0.0, 200.0))
    runs = []
    for acc in (400.0, 900.0):
        tr = simulate({"y": axis}, round_trip(20.0, 120.0, 1500.0, acc, 0.5), rate_hz=1000.0)
        runs.append(prepare_round_trip(tr.to_run(f"rt{acc:.0f}.csv"), spec, "train"))
    theta, _ = fit(compose((compliance_stage(),), 60.0, {}), runs, [np.array([60.0, 40.0, 0.3, 5.0, 200.0])])
    f_true = np.sqrt(150e6 / 1200.0) / (2 * np.pi)
    assert abs(theta[1] - f_true) / f_true < 0.15
