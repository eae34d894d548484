"""Prognosis of an axis' backlash from its history.

The seed paper found b̄ follows temperature (r = 0.935), not wear (r = 0.24). A
maintenance planner still wants two answers: at which shop temperature the tolerance
is lost today, and when wear will have closed the margin. The model:

    b̄(T, d) = b̄20 + β (T - 20 °C) + γ d

with T the machine temperature and d the utility day (days in service). It is fitted
robustly (Huber loss, ``scipy.optimize.least_squares``), so that a few bad cycles do not
steer it; the covariance is Huber's sandwich estimate (Huber 1981, Eq. 7.6.5) on the
linear design, and the intervals are t intervals at ``confidence``.

The fit takes arrays, so a caller can fit any stretch of the history on its own (each
interval between two repairs, say). Whether the history supports it at all is part of
the answer: too few cycles, too narrow a temperature range, temperature and age moving
together, or too short a span of days for γ each give "not identifiable" with the
reason, never a number.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np
from scipy import stats
from scipy.optimize import least_squares

from core.errors import InputError, MebmError, ModelDomainError
from core.tbe.decision import MachiningTask, State, decide

REFERENCE_TEMPERATURE_C = 20.0
DAY_S = 86_400.0
NOT_WITHIN = "not within {years:g} years"


@dataclass(frozen=True)
class PrognosisSettings:
    """When the history supports the fit, and how far to look ahead.

    ``min_cycles``: fewest cycles; ``min_temperature_span_k``: smallest spread of the
    temperatures (max - min) for β; ``min_day_span``: smallest spread of utility days
    for γ (below it γ is held at 0 and no date is given); ``max_abs_correlation``:
    largest |r| between temperature and age (a history where the shop warmed up as the
    axis aged cannot tell the two apart); ``huber_k``: the Huber threshold in robust σ;
    ``horizon_years``: how far the date is sought; ``confidence`` of the intervals."""

    min_cycles: int = 10
    min_temperature_span_k: float = 3.0
    min_day_span: float = 30.0
    max_abs_correlation: float = 0.95
    huber_k: float = 1.345
    horizon_years: float = 5.0
    confidence: float = 0.95
    reference_c: float = REFERENCE_TEMPERATURE_C

    def __post_init__(self) -> None:
        if not 0.0 < self.confidence < 1.0:
            raise InputError(f"confidence (={self.confidence}) must be in (0, 1)")
        if self.min_cycles < 4:
            raise InputError(f"min_cycles (={self.min_cycles}) must be >= 4 (three parameters and a residual)")
        for name in ("min_temperature_span_k", "min_day_span", "huber_k", "horizon_years"):
            v = getattr(self, name)
            if not (math.isfinite(v) and v > 0):
                raise InputError(f"{name} (={v!r}) must be a finite number > 0")


@dataclass(frozen=True)
class Estimate:
    """A fitted value with its standard uncertainty and its ``confidence`` interval."""

    value: float
    standard_uncertainty: float
    low: float
    high: float

    def to_dict(self, unit: str) -> dict:
        return {f"value_{unit}": self.value, f"standard_uncertainty_{unit}": self.standard_uncertainty,
                f"interval_{unit}": [self.low, self.high]}


@dataclass(frozen=True)
class ThermalWearFit:
    """b̄(T, d) = b̄20 + β (T - 20 °C) + γ d. ``identifiable`` False: ``reason`` says why
    and the estimates are None. ``wear_identifiable`` False: γ was held at 0 (its reason
    in ``wear_reason``). ``covariance`` is over (b̄20, β, γ) in µm, µm/K, µm/day."""

    identifiable: bool
    reason: str
    n_cycles: int
    temperature_span_k: float
    day_span: float
    backlash_20c_um: Estimate | None = None
    beta_um_per_k: Estimate | None = None
    gamma_um_per_day: Estimate | None = None
    wear_identifiable: bool = False
    wear_reason: str = ""
    residual_std_um: float | None = None
    covariance: np.ndarray | None = field(default=None, repr=False)
    t_quantile: float = 1.96
    reference_c: float = REFERENCE_TEMPERATURE_C
    outliers_downweighted: int = 0

    def predict_um(self, temperature_c, day) -> tuple[np.ndarray, np.ndarray]:
        """Expected b̄ and its standard uncertainty (of the mean, from the covariance)."""
        if not self.identifiable:
            raise MebmError(f"the prognosis fit is not identifiable: {self.reason}")
        t = np.asarray(temperature_c, float) - self.reference_c
        d = np.asarray(day, float)
        t, d = np.broadcast_arrays(t, d)
        x = np.stack([np.ones_like(t), t, d], axis=-1)
        coef = np.array([self.backlash_20c_um.value, self.beta_um_per_k.value, self.gamma_um_per_day.value])
        mean = x @ coef
        var = np.einsum("...i,ij,...j->...", x, self.covariance, x)
        return mean, np.sqrt(np.maximum(var, 0.0))

    def to_dict(self) -> dict:
        out = {
            "identifiable": self.identifiable, "reason": self.reason, "n_cycles": self.n_cycles,
            "temperature_span_k": self.temperature_span_k, "day_span": self.day_span,
            "wear_identifiable": self.wear_identifiable, "wear_reason": self.wear_reason,
            "reference_temperature_c": self.reference_c,
        }
        if self.identifiable:
            out.update({
                "backlash_20c": self.backlash_20c_um.to_dict("um"),
                "beta": self.beta_um_per_k.to_dict("um_per_k"),
                "gamma": self.gamma_um_per_day.to_dict("um_per_day"),
                "residual_std_um": self.residual_std_um,
                "outliers_downweighted": self.outliers_downweighted,
            })
        return out


def _arrays(temperature_c, day, backlash_um) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    out = []
    for name, a in (("temperature_c", temperature_c), ("day", day), ("backlash_um", backlash_um)):
        try:
            a = np.asarray(a, dtype=float)
        except (TypeError, ValueError) as exc:
            raise InputError(f"{name} must hold numbers ({exc})") from None
        if a.ndim != 1:
            raise InputError(f"{name} must be one-dimensional, got shape {a.shape}")
        out.append(a)
    if not (out[0].shape == out[1].shape == out[2].shape):
        raise InputError(f"temperature_c, day and backlash_um differ in length: {[a.size for a in out]}")
    keep = np.isfinite(out[0]) & np.isfinite(out[1]) & np.isfinite(out[2])
    return out[0][keep], out[1][keep], out[2][keep]


def _robust_sigma(r: np.ndarray) -> float:
    return float(1.4826 * np.median(np.abs(r - np.median(r))))


def fit_thermal_wear(temperature_c, day, backlash_um,
                     settings: PrognosisSettings = PrognosisSettings()) -> ThermalWearFit:
    """Huber fit of b̄(T, d) on the cycles where all three are finite (the others are
    left out and not counted). ``day`` is the utility day of each cycle."""
    t, d, b = _arrays(temperature_c, day, backlash_um)
    n = int(t.size)
    t_span = float(np.ptp(t)) if n else 0.0
    d_span = float(np.ptp(d)) if n else 0.0
    base = dict(n_cycles=n, temperature_span_k=t_span, day_span=d_span, reference_c=settings.reference_c)
    if n < settings.min_cycles:
        return ThermalWearFit(False, f"too few cycles: {n} with a temperature, at least "
                                     f"{settings.min_cycles} needed", **base)
    if t_span < settings.min_temperature_span_k:
        return ThermalWearFit(False, f"too narrow a temperature range: {t.min():.1f}..{t.max():.1f} °C "
                                     f"({t_span:.1f} K < {settings.min_temperature_span_k:g} K), β cannot be "
                                     "told from the scatter", **base)
    wear = d_span >= settings.min_day_span
    wear_reason = "" if wear else (f"the history spans {d_span:.1f} utility days (< {settings.min_day_span:g}): "
                                   "wear is not identifiable, γ held at 0 and no date is given")
    if wear:
        r_td = float(np.corrcoef(t, d)[0, 1])
        if abs(r_td) > settings.max_abs_correlation:
            return ThermalWearFit(False, f"temperature and age move together (r = {r_td:.3f}, |r| > "
                                         f"{settings.max_abs_correlation:g}): their effects cannot be separated",
                                  **base)
    tc = t - settings.reference_c
    d0 = float(np.median(d))  # centred for conditioning; the intercept is moved back below
    cols = [np.ones(n), tc] + ([d - d0] if wear else [])
    x = np.column_stack(cols)
    p = x.shape[1]
    ols, *_ = np.linalg.lstsq(x, b, rcond=None)
    sigma = _robust_sigma(b - x @ ols)
    if not sigma > 0:
        sigma = max(float(np.std(b - x @ ols)), 1e-6)
    c = settings.huber_k * sigma
    sol = least_squares(lambda beta: x @ beta - b, ols, loss="huber", f_scale=c, method="trf")
    coef = sol.x
    r = b - x @ coef
    sigma = _robust_sigma(r) or sigma
    c = settings.huber_k * sigma
    psi = np.clip(r, -c, c)
    inside = np.abs(r) < c
    m = max(float(np.mean(inside)), 1.0 / n)
    # Huber's sandwich: K² Σψ²/(n-p) / (mean ψ')² (X'X)^-1, K the small-sample correction
    k_corr = 1.0 + p / n * (1.0 - m) / m
    try:
        xtx_inv = np.linalg.inv(x.T @ x)
    except np.linalg.LinAlgError:
        return ThermalWearFit(False, "the design is singular (temperature and age collinear)", **base)
    cov = k_corr**2 * float(psi @ psi) / max(n - p, 1) / m**2 * xtx_inv
    if wear:  # back to b̄20 at d = 0: intercept - γ d0
        tr = np.array([[1.0, 0.0, -d0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]])
        coef = tr @ coef
        cov = tr @ cov @ tr.T
    else:
        coef = np.append(coef, 0.0)
        cov = np.pad(cov, ((0, 1), (0, 1)))
    tq = float(stats.t.ppf(0.5 + settings.confidence / 2.0, max(n - p, 1)))

    def est(i: int) -> Estimate:
        u = math.sqrt(max(float(cov[i, i]), 0.0))
        return Estimate(float(coef[i]), u, float(coef[i] - tq * u), float(coef[i] + tq * u))

    return ThermalWearFit(
        True, "", **base, backlash_20c_um=est(0), beta_um_per_k=est(1), gamma_um_per_day=est(2),
        wear_identifiable=wear, wear_reason=wear_reason, residual_std_um=sigma, covariance=cov, t_quantile=tq,
        outliers_downweighted=int(np.count_nonzero(~inside)),
    )


@dataclass(frozen=True)
class Prognosis:
    """The answers for one axis (see the module docstring). Times are seconds since the
    epoch (the caller's clock); ``None`` with a reason where there is no answer."""

    fit: ThermalWearFit
    worst_case_temperature_c: float
    backlash_limit_um: float | None
    binding_task: str | None
    rule: str
    alarm_temperature_c: float | None = None  # ALARM above this shop temperature, today
    alarm_temperature_reason: str = ""
    limit_temperature_c: Estimate | None = None  # b̄ today reaches the backlash limit at this temperature
    limit_date_s: float | None = None  # b̄ at the worst-case temperature reaches the limit then
    limit_date_interval_s: tuple[float | None, float | None] = (None, None)
    limit_date_reason: str = ""
    now_s: float = 0.0
    day_now: float = 0.0
    days_per_second: float = 1.0 / DAY_S  # utility days per calendar second (from the history)

    def to_dict(self, iso=None) -> dict:
        """JSON-ready; ``iso`` turns epoch seconds into a date string (the caller's)."""
        fmt = iso or (lambda s: s)
        lo, hi = self.limit_date_interval_s
        return {
            "fit": self.fit.to_dict(),
            "identifiable": self.fit.identifiable,
            "reason": self.fit.reason,
            "worst_case_temperature_c": self.worst_case_temperature_c,
            "backlash_limit_um": self.backlash_limit_um,
            "binding_task": self.binding_task,
            "decision_rule": self.rule,
            "alarm_temperature_c": self.alarm_temperature_c,
            "alarm_temperature_reason": self.alarm_temperature_reason,
            "limit_temperature": None if self.limit_temperature_c is None else self.limit_temperature_c.to_dict("c"),
            "limit_date": None if self.limit_date_s is None else fmt(self.limit_date_s),
            "limit_date_interval": [None if lo is None else fmt(lo), None if hi is None else fmt(hi)],
            "limit_date_reason": self.limit_date_reason,
            "utility_days_per_day": self.days_per_second * DAY_S,
        }


def _limit_um(task: MachiningTask) -> float:
    """The task's backlash limit; 0 when even no backlash meets its tolerance."""
    try:
        return task.backlash_limit_um()
    except ModelDomainError:
        return 0.0


def _days_per_second(day, time_s) -> float:
    """Utility days per calendar second, from the history (a shop working 5 of 7 days
    ages its axes by 5/7 of a day per day); one per day without a usable history."""
    d, t = np.asarray(day, float), np.asarray(time_s, float)
    ok = np.isfinite(d) & np.isfinite(t)
    d, t = d[ok], t[ok]
    if d.size >= 2 and np.ptp(t) > DAY_S and np.ptp(d) > 0:
        rate = float(np.polyfit(t, d, 1)[0])
        if rate > 0:
            return rate
    return 1.0 / DAY_S


def _alarm_temperature(fit: ThermalWearFit, tasks, day_now: float, u_b: float, warning_fraction: float,
                       rule: str) -> tuple[float | None, str]:
    """Lowest temperature at which a measurement today would make the axis ALARM under
    ``rule`` (b̄ from the fit, its uncertainty ``u_b`` as the latest measurement's)."""
    beta = fit.beta_um_per_k.value

    def alarm(temp: float) -> bool:
        b = float(fit.predict_um(temp, day_now)[0])
        try:
            return decide(max(b, 0.0), tasks, warning_fraction=warning_fraction, backlash_uncertainty_um=u_b,
                          rule=rule).state is State.ALARM
        except ModelDomainError:
            # past Eq. 8's domain (ωT > π/2): beyond every circle's backlash limit, which
            # lies inside the domain, so the tolerance is lost there
            return True

    lo, hi = -20.0, 80.0
    if beta <= 0:
        return None, f"β = {beta:.3g} µm/K <= 0: warming does not widen the backlash"
    if alarm(lo):
        return None, f"ALARM at every shop temperature from {lo:g} °C on"
    if not alarm(hi):
        return None, f"no ALARM below {hi:g} °C"
    for _ in range(40):  # bisection on a monotone verdict: 100 K / 2^40
        mid = 0.5 * (lo + hi)
        lo, hi = (lo, mid) if alarm(mid) else (mid, hi)
    return hi, ""


def prognosis(fit: ThermalWearFit, tasks: Sequence[MachiningTask], *, worst_case_temperature_c: float,
              now_s: float, day_now: float | None = None, days_per_second: float = 1.0 / DAY_S,
              backlash_uncertainty_um: float = 0.0, warning_fraction: float = 0.9, rule: str = "guarded",
              settings: PrognosisSettings = PrognosisSettings()) -> Prognosis:
    """The shop temperature above which the binding task goes ALARM today, the
    temperature at which b̄ reaches the backlash limit (with its interval), and the date
    on which b̄ at ``worst_case_temperature_c`` reaches the limit (with its interval), or
    "not within N years". ``day_now``: today's utility day (None: the fit's newest).
    The backlash limit is the smallest over ``tasks`` (Eq. 7/8 inverse)."""
    if not math.isfinite(worst_case_temperature_c):
        raise InputError(f"worst_case_temperature_c (={worst_case_temperature_c!r}) must be finite")
    if not (math.isfinite(days_per_second) and days_per_second > 0):
        raise InputError(f"days_per_second (={days_per_second!r}) must be > 0")
    base = dict(worst_case_temperature_c=float(worst_case_temperature_c), rule=rule, now_s=float(now_s),
                days_per_second=float(days_per_second))
    limit = binding = None
    if tasks:
        limits = [(_limit_um(t), t.name) for t in tasks]
        limit, binding = min(limits)
        if not math.isfinite(limit):
            limit = None
    if not fit.identifiable:
        return Prognosis(fit, backlash_limit_um=limit, binding_task=binding, day_now=day_now or 0.0,
                         alarm_temperature_reason=fit.reason, limit_date_reason=fit.reason, **base)
    d_now = float(day_now) if day_now is not None else 0.0
    if not tasks:
        why = "the axis has no machining task: nothing limits the backlash"
        return Prognosis(fit, backlash_limit_um=limit, binding_task=binding, day_now=d_now, alarm_temperature_reason=why, limit_date_reason=why,
                         **base)
    t_alarm, t_reason = _alarm_temperature(fit, tasks, d_now, backlash_uncertainty_um, warning_fraction, rule)
    if limit is None:
        why = "no task limits the backlash (every tolerance is met by any backlash)"
        return Prognosis(fit, backlash_limit_um=limit, binding_task=binding, alarm_temperature_c=t_alarm, alarm_temperature_reason=t_reason,
                         limit_date_reason=why, day_now=d_now, **base)
    # the temperature at which b̄ today meets the limit: 20 + (L - b̄20 - γ d) / β, delta method
    b20, beta, gamma = (fit.backlash_20c_um.value, fit.beta_um_per_k.value, fit.gamma_um_per_day.value)
    t_limit = None
    if abs(beta) > 1e-12:
        g = fit.reference_c + (limit - b20 - gamma * d_now) / beta
        grad = np.array([-1.0 / beta, -(g - fit.reference_c) / beta, -d_now / beta])
        u = math.sqrt(max(float(grad @ fit.covariance @ grad), 0.0))
        lo, hi = g - fit.t_quantile * u, g + fit.t_quantile * u
        t_limit = Estimate(float(g), u, float(lo), float(hi))
    # the date: scan the mean and its confidence band over the horizon
    horizon_s = settings.horizon_years * 365.25 * DAY_S
    ts = now_s + np.linspace(0.0, horizon_s, 4001)
    days = d_now + (ts - now_s) * days_per_second
    mean, se = fit.predict_um(worst_case_temperature_c, days)
    band = fit.t_quantile * se

    def first(curve) -> float | None:
        hit = np.flatnonzero(curve >= limit)
        if hit.size == 0:
            return None
        i = int(hit[0])
        if i == 0:
            return float(ts[0])
        f = (limit - curve[i - 1]) / (curve[i] - curve[i - 1])  # linear between scan points
        return float(ts[i - 1] + f * (ts[i] - ts[i - 1]))

    date, early, late = first(mean), first(mean + band), first(mean - band)
    never = NOT_WITHIN.format(years=settings.horizon_years)
    if date is not None and date <= now_s:
        reason = (f"b̄ at {worst_case_temperature_c:g} °C ({mean[0]:.1f} µm) is at or above the backlash limit "
                  f"({limit:.1f} µm) already")
    elif date is None:
        reason = never + ("" if fit.wear_identifiable else f" ({fit.wear_reason})")
    else:
        reason = ""
    if not fit.wear_identifiable and (date is None or date > now_s):
        date, early, late = None, None, None
    return Prognosis(fit, backlash_limit_um=limit, binding_task=binding, alarm_temperature_c=t_alarm, alarm_temperature_reason=t_reason,
                     limit_temperature_c=t_limit, limit_date_s=date, limit_date_interval_s=(early, late),
                     limit_date_reason=reason, day_now=d_now, **base)


def forecast_band(fit: ThermalWearFit, temperature_c: float, day, confidence_quantile: float | None = None):
    """b̄ at ``temperature_c`` over ``day`` and its band (mean ± t·u): for the plot."""
    mean, se = fit.predict_um(temperature_c, day)
    q = fit.t_quantile if confidence_quantile is None else confidence_quantile
    return mean, mean - q * se, mean + q * se


def days_per_second(day, time_s) -> float:
    """Public form of the utility-day rate (utility days per calendar second)."""
    return _days_per_second(day, time_s)
