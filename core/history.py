"""Long-term tracking (Sections 3.1.2 and 3.2.2): correlations and a thermal model.

The paper found the mean backlash follows temperature (r = 0.94), not wear
(r = 0.24). Beyond the paper, :class:`TemperatureModel` fits
b̄(T) = b̄_20 + beta (T - 20 °C), so a backlash can be reported normalised to
20 °C (the ISO 1 reference temperature) and the TBE predicted at the shop's
worst-case temperature.
"""

from __future__ import annotations

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
