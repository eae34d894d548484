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

A drive that saturates (a force or current limit: the motor's acceleration held within
±a_max, the position integral frozen while it holds, ``accel_limit_mm_s2``) is a form of
its own (:func:`_fit_limited`), tried on every servo fit and kept where it cuts the
linear forms' train misfit by a quarter with its limit identifiable. The limit is
bounded by the largest acceleration the configured loop asks of the motor on the train
contours: a limit the train contours never reach changes nothing on them (a zero
Jacobian column, no better fit) and is not kept, since a value the train runs never
tested would decide the held-out ones.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import replace

import numpy as np

from core.dataset import AxisSpec
from core.gap.contour import SimMemo, apparent_gain_per_s
from core.gap.data import Contour
from core.gap.families.base import NOT_IDENTIFIABLE, ContourFit, Family
from core.gap.roundtrip import finite_residuals, fit_ls, intervals
from core.gap.stages import NESTED_MIN_CUT
from core.sim import AxisModel, Effects, ServoDynamics

NAME = "servo_dynamics"


def servo_piece(params: Mapping[str, float]) -> ServoDynamics:
    # K_i = K_I / K_eff <= K_eff: the PI loop's damping ratio 0.5 sqrt(K/K_i) stays at 0.5 or more
    k = float(params["position_gain_per_s"])
    ki = min(float(params.get("integral_gain_per_s2", 0.0)) / k, k)
    return ServoDynamics(velocity_lag_s=1e-3 * params["velocity_lag_ms"], dead_time_s=1e-3 * params["dead_time_ms"],
                         feedforward=params["feedforward"], feedback_delay_s=1e-3 * params["feedback_delay_ms"],
                         integral_per_s=max(ki, 0.0),
                         accel_limit_mm_s2=max(float(params.get(LIMIT_NAME, 0.0)), 0.0))  # fmt: skip


SERVO_NAMES = ("position_gain_per_s", "feedforward", "velocity_lag_ms", "dead_time_ms", "feedback_delay_ms",
               "integral_gain_per_s2")  # fmt: skip
SERVO_LOWER = np.array([2.0, 0.0, 0.0, 0.0, 0.0, 0.0])
SERVO_UPPER = np.array([120.0, 1.2, 20.0, 6.0, 6.0, 4000.0])
SERVO_FORMS = (
    "servo_dynamics: effective position gain on both sides of the configured K, velocity feed-forward "
    "fraction, a first-order velocity-loop lag, dead time in the forward and in the feedback path "
    "(interpolated, continuous), integral action in the position loop (a PI loop, K_I = K K_i <= K_eff²), "
    "a drive that saturates (a force or current limit, the motor's acceleration held within ±a_max) where the "
    "train contours reach its limit. Not covered: a resonant velocity loop (it is approximated by the lag), "
    "acceleration feed-forward, friction compensation pulses, a drive limit the train contours never reach."
)
LIMIT_NAME = "accel_limit_mm_s2"
LIMIT_START_FRACTIONS = (0.15, 0.3, 0.5, 0.7)  # of the most the configured loop asks


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

        def model(theta, limit=0.0, a=a, fx0=fx0, spec=spec):
            fx = fx0.with_effect(NAME, servo_piece({**dict(zip(SERVO_NAMES, theta)), LIMIT_NAME: limit}))
            return AxisModel(name=a, transmission_mm_per_rev=spec.transmission_mm_per_rev,
                             screw_lead_mm=spec.screw_lead_mm, position_gain_per_s=float(theta[0]),
                             backlash_um=max(0.0, float(backlash_um.get(a, 0.0))), effects=fx)  # fmt: skip

        def res(theta, limit=0.0, a=a, mine=mine):
            m = model(theta, limit)
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
        configured = np.array([k, 0.0, 0.0, 0.0, 0.0, 0.0])  # the configured P loop
        asked = max(peak_accel_mm_s2(memo.motor_mm(c, a, model(configured)), c.rate_hz) for c in mine)
        if asked > 0.0:
            fr = _fit_limited(res, fr, asked, (fr.theta, starts[0]))
        out[a] = fr
        rss += fr.rss
    return out, rss


def peak_accel_mm_s2(x_mm: np.ndarray, rate_hz: float) -> float:
    """The largest |acceleration| of a simulated (noise-free) position record, mm/s²."""
    if x_mm.size < 3:
        return 0.0
    dt = 1.0 / rate_hz
    return float(np.max(np.abs(np.gradient(np.gradient(x_mm, dt), dt))))


def _fit_limited(res, linear, asked_mm_s2: float, froms: Sequence[np.ndarray]):
    """The servo fit with the drive's acceleration limit a_max (``LIMIT_NAME``), from
    ``froms`` (the linear fit's values, the configured loop) with the limit at
    :data:`LIMIT_START_FRACTIONS` of ``asked_mm_s2``, the most the configured loop asks of
    the motor on the train contours and the limit's upper bound (the cost is multi-modal
    in the limit: a limit that clips one contour's start and one that clips all of them
    are separate minima). A linear fit to a saturated drive bends its gain and lags to
    follow the clipped motion, so the configured loop is a start of its own. The best
    start is pursued only where it already fits better than the linear fit. Kept over
    the ``linear`` fit where it cuts its train RSS by
    :data:`core.gap.stages.NESTED_MIN_CUT`, as any form that extends another of its
    family, and the limit is identifiable: a limit just under the largest demand trims
    the sharpest start of a contour (where the configured loop, without the drive's lag,
    asks more than any drive gives) by a few per mille of the RSS, which a BIC test on
    thousands of correlated samples would take for a saturating drive."""
    names = SERVO_NAMES + (LIMIT_NAME,)
    lower = np.r_[SERVO_LOWER, 0.02 * asked_mm_s2]
    upper = np.r_[SERVO_UPPER, asked_mm_s2]
    starts = [np.clip(np.r_[th, f * asked_mm_s2], lower + 1e-9, upper - 1e-9) for th in froms
              for f in LIMIT_START_FRACTIONS]  # fmt: skip

    def limited(th):
        return res(th[:-1], th[-1])

    # pursued from the best start only where one already fits the train contours better
    # than the linear fit: a drive that never saturates is clipped by every start
    costs = [float(np.sum(finite_residuals(limited(th)) ** 2)) for th in starts]
    best = int(np.argmin(costs))
    if not costs[best] < linear.rss:
        return linear
    lim = fit_ls(limited, [starts[best]], lower, upper, max_nfev=20, diff_step=1e-3)
    if not 0.0 < lim.rss <= (1.0 - NESTED_MIN_CUT) * linear.rss:
        return linear
    if intervals(lim, names, lower, upper)[LIMIT_NAME] is None:
        return linear
    return replace(lim, names=names, lower=lower, upper=upper)


def identifiable(d, f) -> tuple[bool, str | None]:
    if not d.train_ct:
        return False, f"{NOT_IDENTIFIABLE} from round trips (acts between command and motor)"
    return True, None


FAMILY = Family(NAME, SERVO_FORMS, None, identifiable=identifiable,
                contour_fit=ContourFit(SERVO_NAMES, SERVO_LOWER, SERVO_UPPER,
                                       lambda d, bl, pieces: fit_servo(d.memo, d.train_ct, d.axes, bl, pieces)[0],
                                       servo_piece, gain="position_gain_per_s"))  # fmt: skip
