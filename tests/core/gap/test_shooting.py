"""Multiple shooting of a chain kernel's train fit (the stop-36 experiment): the table
restarts from its measured state every ``SHOOT_HORIZON_S``, so that a train run whose
table rattles in another cycle than the model's (a multistable chain) cannot dominate the
fit; test runs are always predicted through, from their start."""

import numpy as np

from core.gap import candidates as C
from core.gap.data import RoundTrip
from core.gap.play import play, play_inertia

RATE_HZ = 1000.0


def _stroke():
    t = np.arange(int(3.0 * RATE_HZ)) / RATE_HZ
    u = np.where(t < 0.5, 0.0, np.where(t < 1.5, 20.0 * (t - 0.5), 20.0 - 20.0 * (t - 1.5)))  # mm
    return t, u


def test_a_restart_from_the_free_runs_own_state_keeps_the_prediction():
    t, u = _stroke()
    w, hb = 2 * np.pi * 60.0, np.full(t.size, 0.03)
    args = (u, np.gradient(u, t), t, hb, w * w, 0.3 * w, 2.0, 200.0, 20, -0.03)
    free = play_inertia(*args)
    idx = np.arange(150, t.size, 100, dtype=np.int64)  # away from the strokes' kinks (the velocity estimate)
    vel = np.gradient(free, t)
    shot = play_inertia(*args, 0.0, 0.0, idx, free[idx], vel[idx])
    assert np.max(np.abs(shot - free)) * 1e3 < 0.5  # µm: only the velocity estimate differs
    moved = play_inertia(*args, 0.0, 0.0, idx[:1], free[idx[:1]] + 0.02, vel[idx[:1]])
    assert abs(moved[idx[0] + 1] - free[idx[0] + 1]) * 1e3 > 15.0  # the restart takes effect


def test_the_restart_states_carry_the_table_encoders_zero_to_the_model():
    t, u = _stroke()
    hb = 0.04
    x_model = play(u, np.full(u.size, hb), u[0] + hb)
    zero_mm = 0.1234  # the table encoder reads this much more than the model's coordinates
    run = RoundTrip("rt.csv", "x", "train", t, u, x_model + zero_mm, 20.0, 1200.0, None, 1, np.arange(t.size))
    idx, x_reset, v_reset = C.shooting_states(run, u, {}, 0.1)
    assert np.array_equal(idx, np.arange(0, t.size, 100))
    assert np.max(np.abs(x_reset - x_model[idx])) * 1e3 < 1.0
    assert np.max(np.abs(v_reset - np.gradient(x_model, t)[idx])) < 1.0  # mm/s


def test_only_the_chain_kernels_train_fit_shoots():
    comp = C.compose((C.compliance_stage(),), 50.0, {})
    lost_motion = C.compose((C.friction_stage(),), 50.0, {})
    assert comp.predict_train is not None and lost_motion.predict_train is None
    assert C.compose((), 50.0, {}).predict_train is None
