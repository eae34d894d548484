"""Restarts of the compliance form's train prediction where the measured table starts to
rattle (stop 37): a rattling chain is multistable, and a train run whose table rattles in
another cycle than the model's must not dominate the fit; test runs are always predicted
through, from their start."""

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


def _rattling_run(zero_mm=0.0):
    """A stroke whose table, in the middle of the backlash, rattles at 30 Hz, ±20 µm, from
    1.2 s to 1.4 s and again from 2.2 s on; the table encoder reads ``zero_mm`` more than
    the model's coordinates."""
    t, u = _stroke()
    hb = 0.04
    x_model = play(u, np.full(u.size, hb), u[0] + hb)
    burst = ((t >= 1.2) & (t < 1.4)) | (t >= 2.2)
    x_model = x_model + np.where(burst, 0.02 * np.sin(2 * np.pi * 30.0 * t), 0.0)
    return RoundTrip("rt.csv", "x", "train", t, u, x_model + zero_mm, 20.0, 1200.0, None, 1, np.arange(t.size)), x_model


def test_rattle_onsets_are_found_where_the_table_starts_to_rattle():
    run, _ = _rattling_run()
    t_on = run.t_s[C.rattle_onsets(run)]
    # the first motion (0.5 s) and the reversal (1.5 s) step by the backlash: onsets too
    assert t_on.size == 4
    assert np.all(np.abs(t_on - [0.5, 1.2, 1.5, 2.2]) < 0.04)
    quiet = RoundTrip("q.csv", "x", "train", run.t_s, run.u_mm, play(run.u_mm, np.full(run.u_mm.size, 0.04),
                      run.u_mm[0] + 0.04), 20.0, 1200.0, None, 1, np.arange(run.t_s.size))  # fmt: skip
    t_quiet = run.t_s[C.rattle_onsets(quiet)]
    assert t_quiet.size == 2 and np.all(np.abs(t_quiet - [0.5, 1.5]) < 0.04)


def test_the_restart_states_carry_the_table_encoders_zero_to_the_model():
    run, x_model = _rattling_run(zero_mm=0.1234)
    idx, x_reset, v_reset = C.shooting_states(run, run.u_mm, {})
    lead = int(round(C.RATTLE_LEAD_S * RATE_HZ))
    assert np.array_equal(idx, C.rattle_onsets(run) - lead)
    assert np.max(np.abs(x_reset - x_model[idx])) * 1e3 < 1.0
    assert np.max(np.abs(v_reset - np.gradient(x_model, run.t_s)[idx])) < 1.0  # mm/s


def test_restarts_never_precede_the_first_compared_sample():
    run, _ = _rattling_run()
    late = RoundTrip(run.file, "x", "train", run.t_s, run.u_mm, run.x_mm, 20.0, 1200.0, None, 1,
                     np.arange(run.t_s.size), start=int(1.15 * RATE_HZ))  # fmt: skip
    idx, _, _ = C.shooting_states(late, late.u_mm, {})
    assert idx.min() >= late.start and idx[0] == late.start


def test_only_the_compliance_forms_train_fit_restarts():
    comp = C.compose((C.compliance_stage(),), 50.0, {})
    lost_motion = C.compose((C.friction_stage(),), 50.0, {})
    chain = C.compose((C.friction_chain_stage(),), 50.0, {})
    assert comp.predict_train is not None
    assert lost_motion.predict_train is None and chain.predict_train is None
    assert C.compose((), 50.0, {}).predict_train is None


def test_a_restarted_train_prediction_follows_the_measured_rattle():
    """The compliance form with a train run that rattles where the model does not: the
    restarted prediction starts each rattle from the measured state, the free run does not."""
    run, _ = _rattling_run()
    comp = C.compose((C.compliance_stage(),), 80.0, {})
    theta = comp.x0.copy()
    free, restarted = comp.predict(theta, run), comp.predict_train(theta, run)
    idx, x_reset, v_reset = C.shooting_states(run, C.smooth_u(run, {}, C.COMPLIANCE_SMOOTH_POSITION_S,
                                                                C.COMPLIANCE_SMOOTH_VELOCITY_S)[0], {})  # fmt: skip
    # one sample after each restart the table is where its measured state carries it
    assert np.max(np.abs(restarted[idx + 1] - (x_reset + v_reset / RATE_HZ))) * 1e3 < 2.0
    assert not np.allclose(free, restarted)
