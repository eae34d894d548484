"""Long-term tracking (Sections 3.1.2 and 3.2.2): correlations and a thermal model.

The paper found the mean backlash follows temperature (r = 0.94), not wear
(r = 0.24). Beyond the paper, :class:`TemperatureModel` fits
b̄(T) = b̄_20 + beta (T - 20 °C), so a backlash can be reported normalised to
20 °C (the ISO 1 reference temperature) and the TBE predicted at the shop's
worst-case temperature.
"""

from __future__ import annotations

import math
from collections.abc import Mapping

import numpy as np
from scipy import stats

from core.errors import InputError, NotFittedError

REFERENCE_TEMPERATURE_C = 20.0


def _finite_pair(x, y, name_x: str, name_y: str) -> tuple[np.ndarray, np.ndarray]:
    a = np.asarray(x, dtype=float)
    b = np.asarray(y, dtype=float)
    if a.shape != b.shape or a.ndim != 1:
        raise InputError(f"{name_x} and {name_y} must be 1-D arrays of equal length, got {a.shape} and {b.shape}")
    if not (np.all(np.isfinite(a)) and np.all(np.isfinite(b))):
        raise InputError(f"{name_x} and {name_y} must be finite (NaN or inf found)")
    return a, b


def pearson_r(x, y) -> float | None:
    """Pearson product-moment correlation (Eq. 4): cov(X, Y) / (σ_X σ_Y).

    ``None`` when it is undefined: fewer than 3 pairs, or either series constant.
    """
    a, b = _finite_pair(x, y, "x", "y")
    if a.size < 3 or np.ptp(a) == 0 or np.ptp(b) == 0:
        return None
    return float(stats.pearsonr(a, b).statistic)


def correlation_table(
    criteria: Mapping[str, np.ndarray], against: Mapping[str, np.ndarray]
) -> dict[str, dict[str, float | None]]:
    """r of every criterion (e.g. ``backlash_mean_um``) against every driver (e.g. ``temperature_c``)."""
    return {c: {k: pearson_r(v, w) for k, w in against.items()} for c, v in criteria.items()}


class TemperatureModel:
    """Linear thermal model of the mean backlash: b̄(T) = b̄_20 + beta (T - 20 °C).

    ``fit`` needs at least two distinct temperatures. Fitted values end in ``_``.
    """

    def __init__(self, reference_c: float = REFERENCE_TEMPERATURE_C):
        self.reference_c = float(reference_c)

    def fit(self, temperature_c, backlash_um) -> TemperatureModel:
        t, b = _finite_pair(temperature_c, backlash_um, "temperature_c", "backlash_um")
        if t.size < 2 or np.ptp(t) == 0:
            raise InputError("a temperature model needs measurements at two or more temperatures")
        res = stats.linregress(t - self.reference_c, b)
        self.backlash_ref_um_ = float(res.intercept)
        self.beta_um_per_k_ = float(res.slope)
        self.r_ = float(res.rvalue) if t.size > 2 else None
        self.n_ = int(t.size)
        resid = b - (res.intercept + res.slope * (t - self.reference_c))
        self.residual_std_um_ = float(np.sqrt(np.sum(resid**2) / max(t.size - 2, 1)))
        self.beta_uncertainty_um_per_k_ = self._u_beta(float(np.sum((t - t.mean()) ** 2)))
        return self

    def _u_beta(self, cxx: float) -> float:
        """Standard uncertainty of β: s / √Σ(T - T̄)² (0 with no residual degree of freedom)."""
        if self.n_ <= 2 or not cxx > 0:
            return 0.0
        return float(self.residual_std_um_ / math.sqrt(cxx))

    def fit_sums(self, sums: MomentSums) -> TemperatureModel:
        """:meth:`fit` from the :class:`MomentSums` of (temperature_c, backlash_um)."""
        if sums.n < 2 or sums.x_max <= sums.x_min:
            raise InputError("a temperature model needs measurements at two or more temperatures")
        cxx, cyy, cxy = sums._centred()
        slope = cxy / cxx
        mean_t = sums.x0 + sums.sx / sums.n
        mean_b = sums.y0 + sums.sy / sums.n
        self.beta_um_per_k_ = float(slope)
        self.backlash_ref_um_ = float(mean_b + slope * (self.reference_c - mean_t))
        self.r_ = sums.pearson_r() if sums.n > 2 else None
        self.n_ = int(sums.n)
        self.residual_std_um_ = float(math.sqrt(max(cyy - slope * cxy, 0.0) / max(sums.n - 2, 1)))
        self.beta_uncertainty_um_per_k_ = self._u_beta(cxx)
        return self

    def _check(self) -> None:
        if not hasattr(self, "beta_um_per_k_"):
            raise NotFittedError("TemperatureModel is not fitted: call fit() first")

    def predict_um(self, temperature_c) -> np.ndarray:
        """Expected mean backlash at ``temperature_c``."""
        self._check()
        return self.backlash_ref_um_ + self.beta_um_per_k_ * (np.asarray(temperature_c, float) - self.reference_c)

    def normalise_um(self, backlash_um, temperature_c) -> np.ndarray:
        """A backlash measured at ``temperature_c`` referred to the reference temperature."""
        self._check()
        return np.asarray(backlash_um, float) - self.beta_um_per_k_ * (
            np.asarray(temperature_c, float) - self.reference_c
        )


class MomentSums:
    """Sufficient statistics of the finite (x, y) pairs of a series: count, sums, sums of
    squares and cross products, and the ranges. Sums of disjoint parts add up, so a
    long history can be summarised per hour and the correlation and the thermal model
    of any union of hours computed without reading its rows (:meth:`pearson_r`,
    :meth:`TemperatureModel.fit_sums`). Sums about a fixed origin (``x0``, ``y0``) keep
    the cancellation small for values far from zero."""

    FIELDS = ("n", "sx", "sy", "sxx", "syy", "sxy", "x_min", "x_max", "y_min", "y_max")

    def __init__(self, n: int = 0, sx: float = 0.0, sy: float = 0.0, sxx: float = 0.0, syy: float = 0.0,
                 sxy: float = 0.0, x_min: float = math.inf, x_max: float = -math.inf, y_min: float = math.inf,
                 y_max: float = -math.inf, x0: float = 0.0, y0: float = 0.0):  # fmt: skip
        self.n, self.sx, self.sy, self.sxx, self.syy, self.sxy = int(n), sx, sy, sxx, syy, sxy
        self.x_min, self.x_max, self.y_min, self.y_max = x_min, x_max, y_min, y_max
        self.x0, self.y0 = float(x0), float(y0)

    @classmethod
    def of(cls, x, y, x0: float = 0.0, y0: float = 0.0) -> MomentSums:
        """The sums of the pairs of ``x`` and ``y`` where both are finite (None is NaN)."""
        a = np.asarray(x, dtype=float)
        b = np.asarray(y, dtype=float)
        if a.shape != b.shape or a.ndim != 1:
            raise InputError(f"x and y must be 1-D arrays of equal length, got {a.shape} and {b.shape}")
        keep = np.isfinite(a) & np.isfinite(b)
        a, b = a[keep], b[keep]
        if a.size == 0:
            return cls(x0=x0, y0=y0)
        da, db = a - x0, b - y0
        return cls(int(a.size), float(da.sum()), float(db.sum()), float(da @ da), float(db @ db), float(da @ db),
                   float(a.min()), float(a.max()), float(b.min()), float(b.max()), x0, y0)  # fmt: skip

    def __add__(self, other: MomentSums) -> MomentSums:
        if (self.x0, self.y0) != (other.x0, other.y0):
            raise InputError(f"sums about different origins cannot be added ({self.x0, self.y0} and {other.x0, other.y0})")
        return MomentSums(self.n + other.n, self.sx + other.sx, self.sy + other.sy, self.sxx + other.sxx,
                          self.syy + other.syy, self.sxy + other.sxy, min(self.x_min, other.x_min),
                          max(self.x_max, other.x_max), min(self.y_min, other.y_min), max(self.y_max, other.y_max),
                          self.x0, self.y0)  # fmt: skip

    def to_list(self) -> list[float | None]:
        """The fields in :attr:`FIELDS` order (JSON-safe: an empty range is None)."""
        return [(float(v) if math.isfinite(v) else None) for v in (getattr(self, f) for f in self.FIELDS)]

    @classmethod
    def from_list(cls, v, x0: float = 0.0, y0: float = 0.0) -> MomentSums:
        return cls(*[float(x) if x is not None else (math.inf if i in (6, 8) else -math.inf) if i >= 6 else 0.0
                     for i, x in enumerate(v)], x0=x0, y0=y0)  # fmt: skip

    def _centred(self) -> tuple[float, float, float]:
        n = self.n
        return (self.sxx - self.sx**2 / n, self.syy - self.sy**2 / n, self.sxy - self.sx * self.sy / n)

    def pearson_r(self) -> float | None:
        """As :func:`pearson_r` on the pairs: None for fewer than 3 or a constant series."""
        if self.n < 3 or self.x_max <= self.x_min or self.y_max <= self.y_min:
            return None
        cxx, cyy, cxy = self._centred()
        if cxx <= 0 or cyy <= 0:
            return None
        return float(np.clip(cxy / math.sqrt(cxx * cyy), -1.0, 1.0))


THERMOMETER_UNCERTAINTY_K = 0.25  # standard: a class B Pt100 (±0.3 K + 0.005 |T|) near 20 °C, rectangular


def history_uncertainty(temperature_c: float | None, recent_temperature_c, recent_backlash_um, *,
                        beta_um_per_k: float | None = None, beta_uncertainty_um_per_k: float = 0.0,
                        thermometer_uncertainty_k: float = THERMOMETER_UNCERTAINTY_K,
                        min_cycles: int = 5) -> dict[str, tuple[float, str]]:
    """The history's components of b̄'s budget (standard uncertainties, µm, with a note):

    - ``repeatability``: the scatter (s, n - 1) of b̄ over recent cycles at a similar
      temperature (the caller picks them), each moved to ``temperature_c`` with β when
      known; given from ``min_cycles`` cycles on. It holds the noise of a single run too,
      so it is an upper estimate of what repeats between runs (GUM 4.2.2, Type A);
    - ``normalisation``: of b̄ referred to 20 °C, b̄ - β (T - 20): √((T - 20)² u(β)² + β² u(T)²),
      u(T) the thermometer's standard uncertainty (GUM 5.1.2, uncorrelated).
    """
    out: dict[str, tuple[float, str]] = {}
    t = np.asarray(recent_temperature_c, dtype=float)
    b = np.asarray(recent_backlash_um, dtype=float)
    keep = np.isfinite(b) & (np.isfinite(t) if t.shape == b.shape else True)
    b = b[keep]
    if t.shape == keep.shape:
        t = t[keep]
    if b.size >= min_cycles:
        moved = b
        if beta_um_per_k is not None and temperature_c is not None and t.shape == b.shape:
            moved = b - beta_um_per_k * (t - temperature_c)
        s = float(np.std(moved, ddof=1))
        out["repeatability"] = (s, f"s of b̄ over the last {b.size} cycles within ±1 K"
                                   + (", moved to this temperature with β" if moved is not b else ""))
    if beta_um_per_k is not None and temperature_c is not None:
        dt = temperature_c - REFERENCE_TEMPERATURE_C
        u = math.hypot(dt * beta_uncertainty_um_per_k, beta_um_per_k * thermometer_uncertainty_k)
        out["normalisation"] = (u, f"β {beta_um_per_k:.3g} ± {beta_uncertainty_um_per_k:.2g} µm/K over "
                                   f"{dt:+.1f} K, thermometer u(T) {thermometer_uncertainty_k:g} K")
    return out
