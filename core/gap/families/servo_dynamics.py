"""The servo-dynamics family: the position and velocity loops between the command and the motor.

It has no round-trip stage: it acts between the command and the motor and leaves the
table-given-motor relation unchanged. It is fitted on the train contours' tracking error
(:func:`fit_servo`), with a linearised start from the lag of the table behind the command.

Forms (one fit, :data:`SERVO_NAMES`): a P position loop with an effective gain on both
sides of the configured K, velocity feed-forward, a first-order velocity-loop lag, dead
time in the forward and the feedback path; and integral action in the position loop
(a PI loop, v = K e + K_I ∫e dt + ..., K_I = K K_i), whose integral gain K_I (1/s²) is
fitted on every contour fit: at K_I = 0 its effect on the tracking error is first order
(the integral of the lag), so the train contours say whether it is there, and a P loop
is its lower bound. K_I is held at K_eff² or less (K_i <= K_eff: the loop's damping
ratio 0.5 or more with an ideal velocity loop). K_I and feed-forward both remove the lag
at steady speed: they are told apart by the contours' start and the settling after it,
and where the train contours cannot, K_I's interval says "not identifiable".

Not covered: a drive that saturates (a force or current limit, ``accel_limit_mm_s2`` in
the twin) as a limit of its own. It acts only in the hardest accelerations: on train
contours that stay below it its parameter changes nothing (a zero Jacobian column,
which makes the whole fit not identifiable), and a value the train runs never tested
would decide the held-out ones (docs/gap-diagnosis.md §4).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import numpy as np

from core.dataset import AxisSpec
from core.gap.contour import SimMemo, apparent_gain_per_s
from core.gap.data import Contour
from core.gap.families.base import NOT_IDENTIFIABLE, ContourFit, Family
from core.gap.roundtrip import fit_ls
from core.sim import AxisModel, Effects, ServoDynamics

NAME = "servo_dynamics"


def servo_piece(params: Mapping[str, float]) -> ServoDynamics:
    # K_i = K_I / K_eff <= K_eff: the PI loop's damping ratio 0.5 sqrt(K/K_i) stays at 0.5 or more
    k = float(params["position_gain_per_s"])
    ki = min(float(params.get("integral_gain_per_s2", 0.0)) / k, k)
    return ServoDynamics(velocity_lag_s=1e-3 * params["velocity_lag_ms"], dead_time_s=1e-3 * params["dead_time_ms"],
                         feedforward=params["feedforward"], feedback_delay_s=1e-3 * params["feedback_delay_ms"],
                         integral_per_s=max(ki, 0.0))  # fmt: skip


SERVO_NAMES = ("position_gain_per_s", "feedforward", "velocity_lag_ms", "dead_time_ms", "feedback_delay_ms",
               "integral_gain_per_s2")  # fmt: skip
SERVO_LOWER = np.array([2.0, 0.0, 0.0, 0.0, 0.0, 0.0])
SERVO_UPPER = np.array([120.0, 1.2, 20.0, 6.0, 6.0, 4000.0])
SERVO_FORMS = (
    "servo_dynamics: effective position gain on both sides of the configured K, velocity feed-forward "
    "fraction, a first-order velocity-loop lag, dead time in the forward and in the feedback path "
    "(interpolated, continuous), integral action in the position loop (a PI loop, K_I = K K_i <= K_eff²). "
    "Not covered: a resonant velocity loop (it is approximated by the lag), acceleration feed-forward, "
    "friction compensation pulses, a drive that saturates (force or current limit)."
)


def fit_servo(memo: SimMemo, contours: Sequence[Contour], axes: Mapping[str, AxisSpec],
              backlash_um: Mapping[str, float], base: Mapping[str, Effects] | None = None):
    """Servo family per contour axis (:data:`SERVO_NAMES`), fitted on
    the train contours' tracking error, one axis at a time (the axes do not interact).
    Starts: the configured K and the apparent gain of the recorded lag, each with and
    without feed-forward. Returns ({axis: FitResult}, train RSS in µm^2)."""
    names = sorted({a for c in contours for a in c.axes})
    out = {}
    rss = 0.0
    for a in names:
        fx0 = (base or {}).get(a) or Effects()
        mine = [c for c in contours if a in c.axes]
        spec = axes[a]

        def res(theta, a=a, fx0=fx0, mine=mine, spec=spec):
            fx = fx0.with_effect(NAME, servo_piece(dict(zip(SERVO_NAMES, theta))))
            m = AxisModel(name=a, transmission_mm_per_rev=spec.transmission_mm_per_rev,
                          screw_lead_mm=spec.screw_lead_mm, position_gain_per_s=float(theta[0]),
                          backlash_um=max(0.0, float(backlash_um.get(a, 0.0))), effects=fx)  # fmt: skip
            return np.concatenate([(c.table_mm[a][c.fit_idx] - memo.axis(c, a, m)[c.fit_idx]) * 1e3 for c in mine])

        k = spec.position_gain_per_s
        k_app = apparent_gain_per_s(mine, a) or k
        starts = [np.array([k, 0.0, 0.5, 0.3, 0.3, 0.0]), np.array([k_app, 0.0, 0.5, 0.3, 0.3, 0.0])]
        if k_app > k:  # lags less than K predicts: feed-forward, or integral action, at the configured gain
            starts.append(np.array([k, float(np.clip(1 - k / k_app, 0, 1)), 0.5, 0.3, 0.3, 0.0]))
            starts += [np.array([k, 0.0, 0.5, 0.3, 0.3, f * k * k]) for f in (0.25, 0.6)]
        for ff in (0.5, 0.9):
            starts.append(np.array([k, ff, 1.0, 0.5, 0.5, 0.0]))
        fr = fit_ls(res, starts, SERVO_LOWER, SERVO_UPPER, n_starts=1, max_nfev=20, diff_step=1e-3)
        out[a] = fr
        rss += fr.rss
    return out, rss


def identifiable(d, f) -> tuple[bool, str | None]:
    if not d.train_ct:
        return False, f"{NOT_IDENTIFIABLE} from round trips (acts between command and motor)"
    return True, None


FAMILY = Family(NAME, SERVO_FORMS, None, identifiable=identifiable,
                contour_fit=ContourFit(SERVO_NAMES, SERVO_LOWER, SERVO_UPPER,
                                       lambda d, bl, pieces: fit_servo(d.memo, d.train_ct, d.axes, bl, pieces)[0],
                                       servo_piece, gain="position_gain_per_s"))  # fmt: skip
