"""Transient backlash error (TBE) from backlash width: the seed paper's Section 4.2.

The model (Fig. 12): proportional position loop with open-loop gain K = k_a k_p
closed on the linear encoder, ideal inner loops, rigid chain with backlash width b.
At a start or reversal the table waits until the motor has traversed b (Eq. 6); the
resulting incoordination between two axes is the TBE.

All functions are vectorised over ``backlash_um`` and return micrometres.
"""

from __future__ import annotations

import numpy as np
from scipy.optimize import brentq

from core.errors import InputError, ModelDomainError, require_finite, require_positive

_SQRT3 = np.sqrt(3.0)


def _backlash_mm(backlash_um: np.ndarray | float) -> np.ndarray:
    try:
        b = np.asarray(backlash_um, dtype=float)
    except (TypeError, ValueError) as exc:
        raise InputError(f"backlash_um (={backlash_um!r}) must be a number or an array of numbers") from exc
    if not np.all(np.isfinite(b)):
        raise InputError("backlash_um contains NaN or inf")
    if np.any(b < 0):
        raise InputError(f"backlash_um (min {b.min():.6g}) must be >= 0")
    return b * 1e-3


def tbe_line_um(backlash_um, angle_deg: float, feed_mm_min: float, gain_per_s: float) -> np.ndarray:
    """TBE of a straight line at ``angle_deg`` to the reversely engaged X axis (Eq. 7).

    The X axis starts reversely engaged, Y directly engaged, both at feed without
    acceleration. Returns the amplitude of the contour error in µm.
    """
    b_mm = _backlash_mm(backlash_um)
    theta = np.deg2rad(require_finite("angle_deg", angle_deg))
    v = require_positive("feed_mm_min", feed_mm_min) / 60.0
    k = require_positive("gain_per_s", gain_per_s)
    c, s = np.cos(theta), np.sin(theta)
    if not c > 1e-12:
        raise InputError(f"angle_deg (={angle_deg}) must be in (-90, 90): the X axis must move")
    eps_mm = s * np.sqrt(2.0 * b_mm * v * c / k) - (v * s * c / k) * (
        1.0 - np.exp(-np.sqrt(2.0 * b_mm * k / (v * c)))
    )
    return np.abs(eps_mm) * 1e3


def circle_delay_s(backlash_um, radius_mm: float, feed_mm_min: float, gain_per_s: float) -> np.ndarray:
    """Delay T until the backlash is traversed after a quadrant point (Eqs. 9-11), in s."""
    b_mm = _backlash_mm(backlash_um)
    r = require_positive("radius_mm", radius_mm)
    omega = require_positive("feed_mm_min", feed_mm_min) / 60.0 / r
    k = require_positive("gain_per_s", gain_per_s)
    delta = 54.0 - 162.0 * k * b_mm * np.sqrt(k * k + omega * omega) / (r * omega * omega)  # Eq. 11
    disc = delta * delta - 2916.0
    # Principal square root: the discriminant is taken as a real number first, so a
    # negative one gives +i√|.| (a complex -0j imaginary part would give -i instead).
    root = np.sqrt(disc.astype(complex))
    # For Δ < -54 the sum Δ + √(Δ²-2916) cancels catastrophically (large b); the
    # product identity (Δ+s)(Δ-s) = 2916 gives the same value without cancellation.
    half_sum = np.where((delta < 0) & (disc > 0), 2916.0 / (delta - root), delta + root) / 2.0
    c = half_sum ** (1.0 / 3.0)  # Eq. 10, principal complex cube root
    with np.errstate(divide="ignore", invalid="ignore"):
        t = ((1 - 1j * _SQRT3) * c / 6.0 + 3.0 * (1 + 1j * _SQRT3) / (2.0 * c) - 1.0) / k  # Eq. 9
    return np.where(b_mm == 0, 0.0, np.real(t))


def circle_steady_lag_um(radius_mm: float, feed_mm_min: float, gain_per_s: float) -> float:
    """How much smaller the circle a P loop traces without backlash is: R (1 - cos φ), µm."""
    r = require_positive("radius_mm", radius_mm)
    omega = require_positive("feed_mm_min", feed_mm_min) / 60.0 / r
    phi = -np.arctan(omega / require_positive("gain_per_s", gain_per_s))
    return float(r * (1.0 - np.cos(phi)) * 1e3)


def tbe_circle_um(backlash_um, radius_mm: float, feed_mm_min: float, gain_per_s: float) -> np.ndarray:
    """TBE at the quadrant transitions of a circle (Eq. 8), in µm.

    This is the radial deviation from the circle the loop traces *without* backlash
    (radius R cos φ). The deviation from the programmed circle is smaller by
    :func:`circle_steady_lag_um`. Raises :class:`ModelDomainError` when the delay
    exceeds a quarter period (ωT > π/2), where Eq. 8 stops being monotone in b.
    """
    r = require_positive("radius_mm", radius_mm)
    omega = require_positive("feed_mm_min", feed_mm_min) / 60.0 / r
    k = require_positive("gain_per_s", gain_per_s)
    t = circle_delay_s(backlash_um, r, feed_mm_min, k)
    wt = omega * t
    if np.any(wt > np.pi / 2):
        raise ModelDomainError(
            f"backlash_um up to {np.max(backlash_um):.6g} delays the axis beyond a quarter turn "
            f"(ωT = {np.max(wt):.3g} rad > π/2) on R = {r} mm at {feed_mm_min} mm/min: outside Eq. 8"
        )
    cphi = np.cos(-np.arctan(omega / k))
    eps_mm = r * (np.sqrt(cphi**2 + cphi**2 * np.sin(wt) ** 2) - cphi)  # Eq. 8
    return eps_mm * 1e3


def circle_backlash_domain_um(radius_mm: float, feed_mm_min: float, gain_per_s: float) -> float:
    """Largest backlash (µm) for which Eq. 8 is valid (ωT = π/2 after the quadrant point)."""
    r = require_positive("radius_mm", radius_mm)
    omega = require_positive("feed_mm_min", feed_mm_min) / 60.0 / r

    def excess(b_um: float) -> float:
        # the very expression tbe_circle_um tests, so the edge found here is accepted there
        return float(omega * circle_delay_s(b_um, r, feed_mm_min, gain_per_s)) - np.pi / 2

    hi = 1.0
    while excess(hi) < 0:
        hi *= 2.0
        if hi > 1e12:  # pragma: no cover - T grows without bound in b
            raise ModelDomainError("could not bound the validity domain of Eq. 8")
    edge = brentq(excess, 0.0, hi, xtol=1e-9, rtol=1e-12)
    # brentq's root may land a few ulps past ωT = π/2, where tbe_circle_um refuses;
    # step back onto the valid side so the edge itself can be evaluated.
    step = np.spacing(edge)
    while excess(edge) > 0.0:
        edge -= step
        step *= 2.0
    return edge


def backlash_limit_um(
    tolerance_um: float,
    *,
    feed_mm_min: float,
    gain_per_s: float,
    radius_mm: float | None = None,
    angle_deg: float | None = None,
    max_backlash_um: float = 5000.0,
) -> float:
    """Largest permissible backlash (µm) whose TBE stays within ``tolerance_um``.

    Give ``radius_mm`` for a circle (Eq. 8) or ``angle_deg`` for a line (Eq. 7).
    The forward map is monotone in b, so a bracketing root finder (Brent) solves it.
    Raises :class:`ModelDomainError` when even b = 0 misses the tolerance, or when no
    backlash up to ``max_backlash_um`` (or the model's validity) reaches it.
    """
    tol = require_positive("tolerance_um", tolerance_um)
    require_positive("feed_mm_min", feed_mm_min)
    require_positive("gain_per_s", gain_per_s)
    if (radius_mm is None) == (angle_deg is None):
        raise InputError("give exactly one of radius_mm (circle) or angle_deg (line)")
    b_hi = require_positive("max_backlash_um", max_backlash_um)
    if radius_mm is not None:
        b_hi = min(b_hi, circle_backlash_domain_um(radius_mm, feed_mm_min, gain_per_s))

        def tbe(b: float) -> float:
            return float(tbe_circle_um(b, radius_mm, feed_mm_min, gain_per_s))
    else:

        def tbe(b: float) -> float:
            return float(tbe_line_um(b, angle_deg, feed_mm_min, gain_per_s))

    if tbe(0.0) > tol:
        raise ModelDomainError(f"tolerance_um (={tol}) cannot be met even with zero backlash")
    if tbe(b_hi) < tol:
        raise ModelDomainError(
            f"tolerance_um (={tol}) is met by any backlash up to {b_hi:.1f} µm "
            f"(TBE there {tbe(b_hi):.2f} µm): the task does not limit the backlash"
        )
    return brentq(lambda b: tbe(b) - tol, 0.0, b_hi, xtol=1e-9, rtol=1e-12)
