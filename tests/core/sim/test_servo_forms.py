"""The servo loop's integral action and the drive's acceleration limit in the twin."""

import numpy as np
import pytest

from core.errors import InputError
from core.sim import AxisModel, Effects, ServoDynamics, round_trip, simulate

FEED_MM_MIN = 1500.0  # 25 mm/s
K_PER_S = 10.0


def _stroke(sd: ServoDynamics, acceleration_mm_s2=500.0):
    axis = AxisModel(name="y", backlash_um=20.0, position_gain_per_s=K_PER_S, effects=Effects(servo_dynamics=sd))
    prog = round_trip(10.0, 110.0, FEED_MM_MIN, acceleration_mm_s2, 0.5, axis="y")
    tr = simulate({"y": axis}, prog, rate_hz=1000.0)
    lag_um = (tr.command_mm["y"] - tr.table_true_mm["y"]) * 1e3
    motor_mm = tr.motor_true_rev["y"] * axis.transmission_mm_per_rev
    # late in the first stroke (4 s) at constant feed: 2.5-3.5 s after its start
    t = tr.time_s
    t_start = float(t[np.argmax(np.abs(np.diff(tr.command_mm["y"])) > 0)])
    mid = (t > t_start + 2.5) & (t < t_start + 3.5)
    return t, lag_um, motor_mm, mid


def test_a_pi_position_loop_leaves_no_lag_at_constant_feed():
    _, lag_p, _, mid = _stroke(ServoDynamics(velocity_lag_s=0.002))
    _, lag_pi, _, _ = _stroke(ServoDynamics(velocity_lag_s=0.002, integral_per_s=5.0))
    v_mm_s = FEED_MM_MIN / 60.0
    assert np.allclose(lag_p[mid], 1e3 * v_mm_s / K_PER_S, atol=0.5)  # the P loop's lag v/K (+ the play)
    assert np.max(np.abs(lag_pi[mid])) < 1.0  # the integral takes it out (poles at -5 ± 5j 1/s)


def test_the_acceleration_limit_holds_the_motor_and_leaves_constant_feed_alone():
    a_max = 100.0
    t, lag_free, motor_free, mid = _stroke(ServoDynamics(velocity_lag_s=0.002), acceleration_mm_s2=None)
    _, lag_lim, motor_lim, _ = _stroke(ServoDynamics(velocity_lag_s=0.002, accel_limit_mm_s2=a_max),
                                       acceleration_mm_s2=None)  # fmt: skip
    dt = t[1] - t[0]
    acc_free = np.abs(np.diff(motor_free, 2)) / dt**2
    acc_lim = np.abs(np.diff(motor_lim, 2)) / dt**2
    assert acc_free.max() > 2 * a_max  # a velocity step: the unlimited drive takes it at K v
    assert acc_lim.max() <= a_max * 1.001
    assert acc_lim.max() >= 0.95 * a_max  # and the limit is reached
    assert np.allclose(lag_lim[mid], lag_free[mid], atol=0.01)  # never at constant feed


def test_a_pi_loop_with_a_saturated_drive_does_not_wind_up():
    """Anti-windup: while the drive is held at its limit the integral does not grow, so the
    overshoot after a velocity step stays near the limited P loop's."""
    sd = ServoDynamics(velocity_lag_s=0.002, integral_per_s=5.0, accel_limit_mm_s2=100.0)
    t, lag, _, mid = _stroke(sd, acceleration_mm_s2=None)
    assert np.max(np.abs(lag[mid])) < 5.0  # settled at constant feed
    first = t < t[mid][-1]  # the first stroke
    # 4 % as the unlimited PI loop (a wound-up integral overshoots by a third of the lag)
    assert -lag[first].min() < 0.1 * lag[first].max()


@pytest.mark.parametrize("field", ["integral_per_s", "accel_limit_mm_s2"])
def test_a_negative_integral_gain_or_limit_is_refused(field):
    with pytest.raises(InputError, match=field):
        ServoDynamics(**{field: -1.0})
