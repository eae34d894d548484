"""Round-trip models of the table given the motor: the nominal one, the fit and its intervals.

Every model predicts the table x(t) from the nut travel u(t) = k_a x_m(t) of one axis
(Eq. 5's play operator plus the effect) and a per-run offset (the motor encoder's
zero is arbitrary: fitted for every model alike, linearly, as the run's mean
residual). Parameters are fitted with ``scipy.optimize.least_squares`` on the train
runs only, in physical units (µm, ppm/K, ms). Friction forces are not identifiable
without the chain stiffness, so friction is fitted as lost motion (µm).

The effects' round-trip stages live in their families (:mod:`core.gap.families`);
:mod:`core.gap.stages` composes them with the nominal play operator into one
:class:`RTModel`. Servo dynamics act between
the command and the motor and leave the table-given-motor relation unchanged, so they
have no round-trip stage.
"""

from __future__ import annotations

import contextvars
import math
import os
import threading
from collections.abc import Callable, Iterator, Sequence
from concurrent.futures import ThreadPoolExecutor
from contextlib import contextmanager
from dataclasses import dataclass, field

import numpy as np
from scipy.ndimage import uniform_filter1d
from scipy.optimize import least_squares
from scipy.optimize._numdiff import approx_derivative  # least_squares' own finite differences

from core.gap.data import REFERENCE_C, RoundTrip
from core.gap.play import play

N_PERIODS = 2  # cyclic error: components fitted
MAX_PERIODOGRAM_SAMPLES = 3000


ENVELOPE_WINDOW_S = 0.05  # as core.gap.contour: slower sample by sample, faster by its envelope


@dataclass(frozen=True)
class RTModel:
    """One candidate model of an axis' round trips.

    ``predict(theta, run) -> x (mm)``; ``theta`` in the units of ``names``; ``x0``,
    ``lower``/``upper`` the start and bounds of the fit; ``n_extra`` the parameters added to
    the nominal model (the backlash).
    """

    effect: str
    names: tuple[str, ...]
    x0: np.ndarray
    lower: np.ndarray
    upper: np.ndarray
    predict: Callable[[np.ndarray, RoundTrip], np.ndarray]
    n_extra: int
    info: dict
    prior: Callable[[np.ndarray], np.ndarray] | None = None  # extra residuals (weak priors)
    # fitted and compared on :func:`residual_env_um` (a chain that stick-slips or hunts)
    envelope: bool = False
    # the windows of its train score when ``envelope`` is set (:func:`residual_train_env_um`)
    train_windows_s: tuple[float, ...] = (ENVELOPE_WINDOW_S,)
    # ``predict`` makes a discrete choice per run (a chain's start place, :class:`RunChoices`):
    # its Jacobian is taken with the choices held
    run_choices: bool = False


def predict_nominal(theta, run: RoundTrip) -> np.ndarray:
    hb = 0.5e-3 * (theta[0] + run.wear_um)
    return play(run.u_mm, np.full(run.u_mm.size, hb), run.start_table_mm(hb))


def nominal_model(b0_um: float) -> RTModel:
    return RTModel("none", ("backlash_um",), np.array([b0_um]), np.array([0.0]), np.array([2000.0]),
                   predict_nominal, 0, {})  # fmt: skip


def residual_um(pred: np.ndarray, run: RoundTrip, idx: np.ndarray | None = None) -> np.ndarray:
    """Measured minus predicted table (µm) with the run's offset removed (its mean)."""
    r = (run.x_mm - pred) * 1e3
    r = r[run.start :] if idx is None else r[idx]
    return r - r.mean()


# Train score of the compliance form (a two-mass chain): the 50 ms split and a 250 ms one,
# at equal weight. A table that rattles across the backlash in one of two cycles (the
# model, driven by the recorded motor, settles into the other until a reversal), or rings
# a few times a second, has the right amplitude and rate in a model with the right
# parameters but not the same phase; sample by sample below 20 Hz that phase dominates the
# train cost, and the fit prefers parameters that damp the motion out. Over 250 ms the
# slow motion is judged by its envelope too. The friction chain is fitted at 50 ms alone,
# the window every test run is scored at.
TRAIN_ENVELOPE_WINDOWS_S = (0.05, 0.25)


def slow_and_envelope(x: np.ndarray, n: int) -> tuple[np.ndarray, np.ndarray]:
    """``x`` split at a window of ``n`` samples: its moving mean, and the moving RMS of the
    rest (the envelope above 1/window). The round trips' and contours' envelope residuals
    and the rattle observation (:func:`core.gap.where.rattles`) all split so."""
    low = uniform_filter1d(x, n, mode="nearest")
    return low, np.sqrt(np.maximum(uniform_filter1d((x - low) ** 2, n, mode="nearest"), 0.0))


def residual_env_um(pred: np.ndarray, run: RoundTrip, idx: np.ndarray | None = None,
                    stacked: bool = False, window_s: float = ENVELOPE_WINDOW_S) -> np.ndarray:
    """Measured against predicted table-minus-nut (µm), sample by sample below 20 Hz and
    by envelope above (the contours' score, :func:`core.gap.contour.envelope_residual_um`):
    each is split into its moving average over 50 ms and the rest, the rest compared by
    its moving RMS; the result is sign(d) sqrt(d^2 + e^2) with the run's offset removed
    from d. A chain that stick-slips or hunts through a stroke (with the loop closed on
    the table scale the motor takes part) has an amplitude and a frequency a model driven
    by the recorded motor can reproduce, but not its phase over seconds. For white noise
    and anything slower than the window its RMS equals that of :func:`residual_um`.
    ``stacked``: (d, e) one after the other (the same sum of squares, smooth to fit).
    ``window_s``: the split's window (50 ms unless a train score asks for another)."""
    n = int(round(window_s / run.dt_s))
    if n < 3 or run.x_mm.size - run.start < 2 * n:
        return residual_um(pred, run, idx)
    measured = run.memo.get(("envelope", n))
    if measured is None:  # the record's split does not change between a fit's evaluations
        measured = run.memo[("envelope", n)] = slow_and_envelope((run.x_mm[run.start :] - run.u_mm[run.start :]) * 1e3, n)
    lm, em = measured
    s = (pred[run.start :] - run.u_mm[run.start :]) * 1e3
    ls, es = slow_and_envelope(s, n)
    d, e = lm - ls, em - es
    if idx is not None:
        d, e = d[idx - run.start], e[idx - run.start]
    d = d - d.mean()
    if stacked:
        return np.concatenate([d, e])
    return np.where(d < 0, -1.0, 1.0) * np.sqrt(d * d + e * e)


def residual_train_env_um(pred: np.ndarray, run: RoundTrip, idx: np.ndarray | None = None,
                          stacked: bool = False,
                          windows_s: Sequence[float] = TRAIN_ENVELOPE_WINDOWS_S) -> np.ndarray:
    """:func:`residual_env_um` over each of ``windows_s``, each weighted 1/sqrt(count) (so
    that white noise keeps its RMS): stacked, one window's after the other; else per
    sample, the root of their squares with the first window's sign."""
    w = 1.0 / math.sqrt(len(windows_s))
    parts = [w * residual_env_um(pred, run, idx, stacked, ws) for ws in windows_s]
    if stacked:
        return np.concatenate(parts)
    return np.where(parts[0] < 0, -1.0, 1.0) * np.sqrt(sum(p * p for p in parts))


def model_residual_um(model: "RTModel", theta: np.ndarray, run: RoundTrip, idx: np.ndarray | None = None,
                      envelope: bool | None = None, stacked: bool = False, train: bool = False,
                      windows_s: Sequence[float] | None = None) -> np.ndarray:
    """The residual a model is fitted and scored on: :func:`residual_env_um` for a model
    whose ``envelope`` is set (or when ``envelope`` says so), else :func:`residual_um`.
    ``train``: the train score, :func:`residual_train_env_um` over ``windows_s`` (default
    the model's ``train_windows_s``) in place of the former."""
    env = model.envelope if envelope is None else envelope
    pred = model.predict(theta, run)
    if not env:
        return residual_um(pred, run, idx)
    if not train:
        return residual_env_um(pred, run, idx, stacked)
    return residual_train_env_um(pred, run, idx, stacked, windows_s or model.train_windows_s)


def train_rss(model: "RTModel", theta: np.ndarray, runs: Sequence[RoundTrip], envelope: bool,
              windows_s: Sequence[float] | None = None) -> float:
    """Sum of squared train residuals (µm^2) in the chosen metric (for an envelope score,
    over ``windows_s``, default the model's own train windows)."""
    return float(sum(np.sum(model_residual_um(model, theta, r, r.fit_idx, envelope, train=True, windows_s=windows_s) ** 2)
                     for r in runs))


@dataclass(frozen=True)
class FitResult:
    """A least-squares fit: parameters, train RSS (µm^2), Jacobian of the residuals at
    the optimum and the number of data residuals (for parameter intervals)."""

    theta: np.ndarray
    rss: float
    jac: np.ndarray
    n_res: int
    capped: bool = False  # the best start stopped at its evaluation cap (max_nfev), not at convergence
    # a fit of a form with more parameters than its family's declared ones: their names and
    # bounds (None: the family's own, ``ContourFit.names``)
    names: tuple[str, ...] | None = None
    lower: np.ndarray | None = None
    upper: np.ndarray | None = None


NONFINITE_RESIDUAL = 1e6  # µm: what a diverged simulation counts as, per sample


def finite_residuals(r) -> np.ndarray:
    """Residuals with a diverged simulation's (NaN or inf) counted as
    :data:`NONFINITE_RESIDUAL`: a bad fit that steers an optimiser away, not a crash."""
    r = np.asarray(r, dtype=float)
    return np.where(np.isfinite(r), r, NONFINITE_RESIDUAL)


@dataclass
class RunChoices:
    """The discrete choices a model's ``predict`` made per run at one parameter vector
    (a chain's start place in its gap, :func:`core.gap.stages._free_start`), and those it
    is to hold. A fit takes its Jacobian with the choices of the point it differentiates
    at held: the derivative is the chosen branch's, not a jump to another start place
    within a finite-difference step, and each column costs one simulation instead of one
    per place."""

    held: dict[int, int] = field(default_factory=dict)  # id(run) -> the choice to make
    made: dict[int, int] = field(default_factory=dict)  # id(run) -> the choice made


_RUN_CHOICES: contextvars.ContextVar[RunChoices | None] = contextvars.ContextVar("mebm_gap_run_choices", default=None)


def run_choices() -> RunChoices | None:
    """The choices the current evaluation records and holds (None: choose freely)."""
    return _RUN_CHOICES.get()


@contextmanager
def choosing(choices: RunChoices) -> Iterator[RunChoices]:
    """Model evaluations in the block record their choices in, and hold those of, ``choices``."""
    token = _RUN_CHOICES.set(choices)
    try:
        yield choices
    finally:
        _RUN_CHOICES.reset(token)


def fit_ls(residuals: Callable[[np.ndarray], np.ndarray], x0s: Sequence[np.ndarray], lower: np.ndarray,
           upper: np.ndarray, n_starts: int = 1, n_prior: int = 0, max_nfev: int | None = None,
           diff_step=None, skip: int = 0, hold_choices: bool = False) -> FitResult:
    """Multi-start trust-region least squares: the ``n_starts`` cheapest of ``x0s`` (one
    evaluation each) start a fit; the best wins. ``skip``: the cheapest ``skip`` starts are
    passed over (a fit again from other starts); the costliest are taken where fewer remain.
    ``hold_choices``: the residuals make discrete choices per run (:class:`RunChoices`);
    the Jacobian is least_squares' own forward differences, with the choices made at the
    point held."""
    def safe(th):
        return finite_residuals(residuals(th))

    last: list = []  # the latest evaluation (theta, residuals, choices made)

    def recorded(th):
        with choosing(RunChoices()) as ch:
            r = safe(th)
        last[:] = [np.array(th, copy=True), r, ch.made]
        return r

    def held_jac(th):
        if not last or not np.array_equal(last[0], th):
            recorded(th)
        with choosing(RunChoices(held=dict(last[2]))):
            return approx_derivative(safe, th, method="2-point", rel_step=diff_step, f0=last[1], bounds=(lower, upper))

    fun, jac = (recorded, held_jac) if hold_choices else (safe, "2-point")

    cands = [np.clip(x0, lower + 1e-9, upper - 1e-9) for x0 in x0s]
    if len(cands) > 1:
        costs = [float(np.sum(fun(th) ** 2)) for th in cands]
        first = min(skip, max(len(cands) - n_starts, 0))
        cands = [cands[i] for i in np.argsort(costs, kind="stable")[first : first + n_starts]]
    best = None
    for x0 in cands:
        kw = {} if diff_step is None else {"diff_step": diff_step}
        try:
            sol = least_squares(fun, x0, jac=jac, bounds=(lower, upper), x_scale="jac", method="trf",
                                max_nfev=max_nfev or 25 * (len(x0) + 1), **kw)  # fmt: skip
        except ValueError:  # the trust region met non-finite numbers: this start fails
            continue
        if best is None or sol.cost < best.cost:
            best = sol
    if best is None:  # every start failed: the first start, unfitted (the candidate will not be taken)
        x0 = cands[0]
        r = fun(x0)
        return FitResult(x0, float(np.sum(r**2)), np.zeros((r.size, x0.size)), int(r.size - n_prior))
    return FitResult(best.x, float(2 * best.cost), best.jac, int(best.fun.size - n_prior), best.status == 0)


def fit(model: RTModel, runs: Sequence[RoundTrip], starts: Sequence[np.ndarray] = (),
        n_starts: int = 1) -> tuple[np.ndarray, float]:
    """Least-squares fit on ``runs``; returns (theta, train RSS in µm^2)."""
    r = fit_model(model, runs, starts, n_starts)
    return r.theta, r.rss


RUN_THREADS = min(os.cpu_count() or 1, 4)  # threads that simulate a fit's runs side by side
_pool: tuple[int, ThreadPoolExecutor] | None = None
_pool_lock = threading.Lock()


def map_runs(fn: Callable[[RoundTrip], np.ndarray], runs: Sequence[RoundTrip]) -> list[np.ndarray]:
    """``[fn(r) for r in runs]``, the runs in up to :data:`RUN_THREADS` threads of one pool
    per process (the chain kernels release the interpreter). The diagnosis fits several
    candidates at once in its own threads; this keeps the cores busy when one long
    chain fit is all that is left."""
    global _pool
    if len(runs) <= 1 or RUN_THREADS <= 1:
        return [fn(r) for r in runs]
    with _pool_lock:
        if _pool is None or _pool[0] != os.getpid():  # a forked child starts its own
            _pool = (os.getpid(), ThreadPoolExecutor(RUN_THREADS, thread_name_prefix="mebm-gap-run"))
        pool = _pool[1]

    def call(r):
        with np.errstate(over="ignore", invalid="ignore"):  # as the diagnosis' own threads
            return fn(r)

    # each run in its own copy of the caller's context: the run choices it records and holds
    ctxs = [contextvars.copy_context() for _ in runs]
    return list(pool.map(lambda c, r: c.run(call, r), ctxs, runs))


def fit_model(model: RTModel, runs: Sequence[RoundTrip], starts: Sequence[np.ndarray] = (),
              n_starts: int = 1, max_nfev: int | None = None, diff_step: float | None = None,
              skip: int = 0) -> FitResult:
    """Least-squares fit of a round-trip model on ``runs``: ``starts`` are extra start
    points beside ``model.x0``; the RSS excludes the priors; ``skip`` as :func:`fit_ls`."""
    n_prior = 0 if model.prior is None else int(np.size(model.prior(model.x0)))

    def one(theta, r):
        return model_residual_um(model, theta, r, r.fit_idx, stacked=True, train=True)

    def res(theta):
        # a chain form's runs are simulated side by side (each run's residual is pure, so
        # the result is the same as one after the other); the others are too quick to gain
        parts = map_runs(lambda r: one(theta, r), runs) if model.envelope else [one(theta, r) for r in runs]
        if model.prior is not None:
            parts.append(model.prior(theta))
        return np.concatenate(parts)

    r = fit_ls(res, [model.x0, *starts], model.lower, model.upper, n_starts, n_prior, max_nfev=max_nfev,
               diff_step=diff_step, skip=skip, hold_choices=model.run_choices)
    rss = train_rss(model, r.theta, runs, model.envelope)
    # the residuals per sample: each window's stacked (d, e) repeats the same samples
    n_res = r.n_res // len(model.train_windows_s) if model.envelope else r.n_res
    return FitResult(r.theta, rss, r.jac, n_res, r.capped)


def intervals(fr: FitResult, names: Sequence[str], lower: np.ndarray, upper: np.ndarray,
              z: float = 1.96) -> dict[str, tuple[float, float] | None]:
    """95 % intervals from the Jacobian at the optimum (s^2 (J'J)^-1, data residuals taken
    as independent: the decimated samples of a run are not quite, so the intervals are
    a lower bound on the true ones). None: the data cannot pin the parameter down (a
    singular J'J, judged on unit-length columns, or an interval wider than half the
    parameter's admissible range)."""
    j = fr.jac[: fr.n_res] if fr.jac.shape[0] >= fr.n_res else fr.jac
    p = len(names)
    dof = max(fr.n_res - p, 1)
    s2 = fr.rss / dof
    # Judged on the columns scaled to unit length (J'J then holds the parameters'
    # correlations): the rank test and the pseudo-inverse's cut-off depend on how nearly
    # the data confuse the parameters, not on the units they are stated in. A column of
    # zeros (a parameter the train data never exercise) stays zero: J'J is singular, and
    # none of the fit's parameters is pinned down (a form fitted with a part the data
    # cannot see is not told from its smaller forms)
    norms = np.sqrt(np.sum(j * j, axis=0))
    scale = 1.0 / np.where(norms > 0.0, norms, 1.0)
    corr = (j * scale).T @ (j * scale)
    try:
        cov = scale[:, None] * np.linalg.pinv(corr, rcond=1e-10, hermitian=True) * scale[None, :] * s2
        sd = np.sqrt(np.clip(np.diag(cov), 0.0, None))
        sv = np.linalg.svd(corr, compute_uv=False, hermitian=True)
        rank_ok = sv.size == 0 or sv[-1] > 1e-12 * sv[0]
    except np.linalg.LinAlgError:
        sd = np.full(p, np.inf)
        rank_ok = False
    out: dict[str, tuple[float, float] | None] = {}
    for i, n in enumerate(names):
        half = z * float(sd[i])
        ok = rank_ok and np.isfinite(half) and half <= 0.5 * float(upper[i] - lower[i]) and not (
            np.isclose(fr.theta[i], lower[i]) and np.isclose(fr.theta[i], upper[i]))
        out[n] = (float(fr.theta[i] - half), float(fr.theta[i] + half)) if ok else None
    return out


def estimate_backlash_um(runs: Sequence[RoundTrip]) -> float:
    """Start value: the median table-minus-nut difference between the two directions."""
    vals = []
    for r in runs:
        v = np.gradient(r.u_mm, r.t_s)
        vmax = np.percentile(np.abs(v), 95)
        d = (r.x_mm - r.u_mm) * 1e3
        pos, neg = d[v > 0.5 * vmax], d[v < -0.5 * vmax]
        if pos.size and neg.size:
            vals.append(np.median(neg) - np.median(pos))
    return float(max(np.median(vals), 0.0)) if vals else 10.0


def residual_periods_mm(runs: Sequence[RoundTrip], resid: Sequence[np.ndarray], lead_mm: float, ka_mm: float,
                        n: int = N_PERIODS) -> tuple[list[float], dict]:
    """The ``n`` strongest periods of the residual versus position (least-squares
    periodogram over 0.5-60 mm on the moving samples), each snapped to the screw lead,
    k_a or one of their first four harmonics when within 2 %."""
    us, rs = [], []
    for run, r in zip(runs, resid):
        i = run.fit_idx
        v = np.gradient(run.u_mm, run.t_s)[i]
        moving = np.abs(v) > 0.3 * np.percentile(np.abs(v), 95)
        for sgn in (1, -1):
            m = moving & (np.sign(v) == sgn)
            if m.sum() > 20:
                us.append(run.u_mm[i][m])
                rs.append(r[m] - r[m].mean())
    if not us:
        return [lead_mm, ka_mm][:n], {}
    u = np.concatenate(us)
    y = np.concatenate(rs)
    if u.size > MAX_PERIODOGRAM_SAMPLES:  # the periodogram costs periods x samples
        keep = np.linspace(0, u.size - 1, MAX_PERIODOGRAM_SAMPLES).astype(int)
        u, y = u[keep], y[keep]
    span = float(np.ptp(u))
    periods = np.geomspace(0.5, min(60.0, max(span / 3, 1.0)), 1500)
    k = 2 * np.pi / periods[:, None]
    s, c = np.sin(k * u), np.cos(k * u)
    power = ((s @ y) ** 2 / np.maximum((s * s).sum(1), 1e-12) + (c @ y) ** 2 / np.maximum((c * c).sum(1), 1e-12))
    known = [lead_mm / h for h in (1, 2, 3, 4)] + [ka_mm / h for h in (1, 2, 3, 4)]
    chosen: list[float] = []
    order = np.argsort(-power)
    for j in order:
        p = float(periods[j])
        if any(abs(p - q) / q < 0.08 for q in chosen):
            continue
        snap = min(known, key=lambda q: abs(p - q) / q)
        if abs(p - snap) / snap < 0.02:
            p = snap
        chosen.append(p)
        if len(chosen) == n:
            break
    top = float(periods[order[0]])
    return chosen, {"dominant_period_mm": top, "power": float(power[order[0]] / max(power.mean(), 1e-30))}


def rms(x: np.ndarray) -> float:
    return float(math.sqrt(np.mean(np.square(x)))) if x.size else float("nan")
