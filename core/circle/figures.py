"""ISO 230-4's figures of a circular test, each with its uncertainty budget.

- Circular deviation G: the radial distance between two concentric circles enclosing
  the path. With both directions it is the bidirectional G(b) of both paths about one
  centre; each direction alone is in ``per_direction``. Two centres:
  least squares (the reference of ISO 230-4 and of ballbar reports) and minimum zone
  (the smallest G any centre gives; never above the least-squares one).
- Circular hysteresis H: the largest radial difference between the ccw and cw paths at
  the same angle (about their common least-squares centre).
- Radial deviation F: the largest and smallest deviation of the path from the nominal
  circle about the nominal centre (F max, F min).
- Centre offset and mean radius deviation: the least-squares circle minus the nominal.
- Reversal spikes: at each quadrant point one axis reverses; the spike is the largest
  radial deviation within ``spike_window_deg`` after the quadrant point (in the pass'
  direction of travel) above the undisturbed path (the pass' deviation, about the
  least-squares centre, on the arcs outside every window, fitted with harmonics of
  order 0-2 and evaluated under the spike), and its width at half that height.

The least-squares circle: a linearised fit (d ≈ a cos θ + b sin θ + c, the limaçon
that ballbar software uses) as the start, then Gauss-Newton on the exact geometric
distances (scipy.optimize.least_squares). The minimum zone: a linear programme on the
linearised radial model (scipy.optimize.linprog, HiGHS), re-linearised once about its
own centre and evaluated exactly; the least-squares centre is a feasible candidate, so
the reported minimum-zone G is the smallest exact G among these centres.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from scipy.optimize import least_squares, linprog

from core.circle.test import DIRECTIONS, QUADRANTS_DEG, CirclePass, CircularTest
from core.criteria.uncertainty import COVERAGE_FACTOR, UncertaintyBudget, UncertaintyComponent
from core.errors import InputError

DEFAULT_SPIKE_WINDOW_DEG = 45.0
_SQRT12 = math.sqrt(12.0)


@dataclass(frozen=True)
class Spike:
    """A reversal spike at ``quadrant_deg`` in the ``direction`` pass, where ``axis`` reverses
    (the first axis at 0° and 180°, the second at 90° and 270°). ``height_um`` above the
    undisturbed circle, ``height_uncertainty_um`` expanded (k = 2), ``width_deg`` at half
    height, ``peak_deg`` where the peak is."""

    axis: str
    quadrant_deg: float
    direction: str
    height_um: float
    height_uncertainty_um: float
    width_deg: float
    peak_deg: float = float("nan")

    def to_dict(self) -> dict:
        return {"axis": self.axis, "quadrant_deg": self.quadrant_deg, "direction": self.direction,
                "height_um": self.height_um, "height_uncertainty_um": self.height_uncertainty_um,
                "width_deg": self.width_deg, "peak_deg": self.peak_deg}


@dataclass(frozen=True)
class CircleFigures:
    """ISO 230-4's figures of one circular test. Every ``*_uncertainty_um`` is expanded
    (k = 2); ``budgets`` holds each figure's components (standard uncertainties, µm)."""

    radius_mm: float
    feed_mm_min: float
    plane: tuple[str, str]
    circular_deviation_um: float
    circular_deviation_mz_um: float
    circular_deviation_uncertainty_um: float
    hysteresis_um: float | None
    hysteresis_uncertainty_um: float | None
    radial_deviation_max_um: float
    radial_deviation_min_um: float
    radial_deviation_uncertainty_um: float
    centre_offset_um: tuple[float, float]
    centre_offset_uncertainty_um: float
    mean_radius_deviation_um: float
    spikes: tuple[Spike, ...]
    per_direction: dict[str, dict]
    mean_radius_deviation_uncertainty_um: float = 0.0
    # the radius of the path away from the reversals (the undisturbed arcs' level) minus the
    # nominal radius: what the loop traces without backlash (a P loop: -R (1 - cos φ))
    undisturbed_radius_deviation_um: float = float("nan")
    undisturbed_radius_deviation_uncertainty_um: float = float("nan")
    centre_offset_mz_um: tuple[float, float] = (0.0, 0.0)
    spike_window_deg: float = DEFAULT_SPIKE_WINDOW_DEG
    noise_um: float = 0.0
    directions: tuple[str, ...] = ()
    minimum_zone_note: str = ""  # empty when the minimum-zone programme solved
    budgets: dict[str, UncertaintyBudget] = field(default_factory=dict)

    def spikes_of(self, axis: str) -> tuple[Spike, ...]:
        """The spikes where ``axis`` reverses."""
        return tuple(s for s in self.spikes if s.axis == axis)

    def to_dict(self) -> dict:
        """JSON-ready, units in the keys."""
        return {
            "radius_mm": self.radius_mm,
            "feed_mm_min": self.feed_mm_min,
            "plane": list(self.plane),
            "directions": list(self.directions),
            "circular_deviation_um": self.circular_deviation_um,
            "circular_deviation_mz_um": self.circular_deviation_mz_um,
            "circular_deviation_uncertainty_um": self.circular_deviation_uncertainty_um,
            "hysteresis_um": self.hysteresis_um,
            "hysteresis_uncertainty_um": self.hysteresis_uncertainty_um,
            "radial_deviation_max_um": self.radial_deviation_max_um,
            "radial_deviation_min_um": self.radial_deviation_min_um,
            "radial_deviation_uncertainty_um": self.radial_deviation_uncertainty_um,
            "centre_offset_um": list(self.centre_offset_um),
            "centre_offset_uncertainty_um": self.centre_offset_uncertainty_um,
            "centre_offset_mz_um": list(self.centre_offset_mz_um),
            "mean_radius_deviation_um": self.mean_radius_deviation_um,
            "mean_radius_deviation_uncertainty_um": self.mean_radius_deviation_uncertainty_um,
            "undisturbed_radius_deviation_um": self.undisturbed_radius_deviation_um,
            "undisturbed_radius_deviation_uncertainty_um": self.undisturbed_radius_deviation_uncertainty_um,
            "minimum_zone_note": self.minimum_zone_note,
            "spike_window_deg": self.spike_window_deg,
            "noise_um": self.noise_um,
            "spikes": [s.to_dict() for s in self.spikes],
            "per_direction": {d: dict(v) for d, v in self.per_direction.items()},
            "uncertainty_budget": {k: b.to_dict() for k, b in self.budgets.items()},
            "coverage_factor": COVERAGE_FACTOR,
        }


# ---------------------------------------------------------------- geometry

def points_um(p: CirclePass, radius_um: float) -> tuple[np.ndarray, np.ndarray]:
    """The path's points about the nominal centre, µm."""
    th = np.deg2rad(p.angle_deg)
    rho = radius_um + p.radial_um
    return rho * np.cos(th), rho * np.sin(th)


def deviation_um(x, y, centre, radius_um: float) -> np.ndarray:
    """Radial deviation about ``centre`` (µm), from the nominal radius."""
    return np.hypot(x - centre[0], y - centre[1]) - radius_um


def _lsq_circle(x: np.ndarray, y: np.ndarray, radius_um: float) -> tuple[np.ndarray, float]:
    """Least-squares circle (centre µm, radius µm): linearised start, then Gauss-Newton on
    the exact distances."""
    th = np.arctan2(y, x)
    d = np.hypot(x, y) - radius_um
    a = np.column_stack([np.cos(th), np.sin(th), np.ones_like(th)])
    (cx, cy, dr), *_ = np.linalg.lstsq(a, d, rcond=None)

    def resid(p):
        return np.hypot(x - p[0], y - p[1]) - (radius_um + p[2])

    def jac(p):
        rho = np.hypot(x - p[0], y - p[1])
        return np.column_stack([-(x - p[0]) / rho, -(y - p[1]) / rho, -np.ones_like(rho)])

    res = least_squares(resid, np.array([cx, cy, dr]), jac=jac, method="lm", xtol=1e-14, ftol=1e-14)
    if not res.success:  # pragma: no cover - a circle fit from a good start converges in a few steps
        raise InputError(f"the least-squares circle did not converge ({res.message})")
    return res.x[:2].copy(), float(radius_um + res.x[2])


def _mz_lp(x, y, centre, radius_um: float) -> np.ndarray | None:
    """One linear programme of the minimum zone, linearised about ``centre``: the centre
    (µm) minimising max - min of d - δa cos θ - δb sin θ; None if the solver fails.

    Solved on the readings that can bound the zone (the highest and lowest ones),
    adding any reading the solution leaves outside its zone until none does: the
    answer is the full problem's, at a fraction of its size."""
    dx, dy = x - centre[0], y - centre[1]
    th = np.arctan2(dy, dx)
    d = np.hypot(dx, dy) - radius_um
    c, s = np.cos(th), np.sin(th)
    span = float(d.max() - d.min()) + 1.0
    bounds = [(-10 * span, 10 * span), (-10 * span, 10 * span), (None, None), (0, None)]
    order = np.argsort(d)
    m = min(d.size, 200)
    active = np.union1d(order[:m], order[-m:])
    tol = 1e-9 * span
    for _ in range(50):
        cc, ss, dd = c[active], s[active], d[active]
        one = np.ones_like(cc)
        # variables (δa, δb, lo, t): lo <= d - δa c - δb s <= lo + t, minimise t
        a_ub = np.block([[np.column_stack([cc, ss, one, 0 * one])], [np.column_stack([-cc, -ss, -one, -one])]])
        res = linprog(np.array([0.0, 0.0, 0.0, 1.0]), A_ub=a_ub, b_ub=np.concatenate([dd, -dd]), bounds=bounds,
                      method="highs")
        if res.status != 0:
            return None
        da, db, lo, t = res.x
        r = d - da * c - db * s
        out = np.flatnonzero((r < lo - tol) | (r > lo + t + tol))
        if not out.size:
            return np.asarray(centre, dtype=float) + res.x[:2]
        worst = out[np.argsort(-np.maximum(lo - r[out], r[out] - lo - t))[:m]]
        active = np.union1d(active, worst)
    return None  # pragma: no cover - each round adds the readings outside the zone


def _min_zone(x, y, lsq_centre, radius_um: float) -> tuple[float, np.ndarray, bool]:
    """Minimum-zone G (µm), its centre, and whether the programme solved: the smallest
    exact G over the least-squares centre and two linearised LP steps."""
    best_c = np.asarray(lsq_centre, dtype=float)
    dev = deviation_um(x, y, best_c, radius_um)
    best_g = float(dev.max() - dev.min())
    c, solved = best_c, True
    for _ in range(2):
        c = _mz_lp(x, y, c, radius_um)
        if c is None:
            solved = False
            break
        dev = deviation_um(x, y, c, radius_um)
        g = float(dev.max() - dev.min())
        if g < best_g:
            best_g, best_c = g, c
    return best_g, best_c, solved


# ---------------------------------------------------------------- uncertainty

def _noise_um(p: CirclePass) -> float:
    """Robust standard deviation of the reading's white noise, from second differences
    along the run (a smooth path has none; a spike's edges are few samples)."""
    d2 = np.diff(p.radial_um, 2)
    if d2.size < 3:
        return 0.0
    mad = float(np.median(np.abs(d2 - np.median(d2))))
    return 1.4826 * mad / math.sqrt(6.0)


def _extremes_factor(n: int) -> float:
    """How far the largest of n independent normal readings lies above their mean, in σ."""
    return max(1.0, math.sqrt(2.0 * math.log(max(n, 1))))


def _resolution(test: CircularTest, factor: float, what: str) -> UncertaintyComponent:
    q = test.instrument.resolution_um
    if q == 0:
        return UncertaintyComponent("resolution", 0.0, "0: the radial reading is not quantised")
    return UncertaintyComponent("resolution", factor * q / _SQRT12,
                                f"q {q:.3g} µm, rectangular, {what}")


def _accuracy(test: CircularTest, factor: float, what: str) -> UncertaintyComponent:
    a = test.instrument.accuracy_um
    kind = test.instrument.kind
    if factor == 0:
        return UncertaintyComponent("accuracy", 0.0, f"0: {what}")
    if a == 0:
        return UncertaintyComponent("accuracy", 0.0, f"0: the {kind} reading is stated to be exact")
    return UncertaintyComponent("accuracy", factor * a, f"{kind} accuracy {a:.3g} µm (standard), {what}")


def _noise(sigma: float, factor: float, what: str) -> UncertaintyComponent:
    if sigma == 0:
        return UncertaintyComponent("noise", 0.0, "0: the data show no scatter")
    return UncertaintyComponent("noise", factor * sigma, f"σ {sigma:.3g} µm from second differences, {what}")


def _between_samples_um(v: np.ndarray, i: int) -> float:
    """How far the path may pass beyond the sampled maximum ``v[i]`` between samples: the
    rising line through (i-1, i) meets the falling line through (i+1, i+2) (and likewise
    one sample earlier) where a cusp (a reversal's spike) would peak; at most the step to
    the lower neighbour, at least 0."""
    n = v.size
    step = max((v[i] - v[j] for j in (i - 1, i + 1) if 0 <= j < n), default=0.0)
    best = 0.0
    for a in (i - 1, i):  # the peak between samples a and a + 1
        if a - 1 < 0 or a + 2 >= n:
            best = max(best, step)
            continue
        s_left, s_right = v[a] - v[a - 1], v[a + 2] - v[a + 1]
        if not s_left > s_right:
            continue
        t = min(max((v[a + 1] - s_right - v[a]) / (s_left - s_right), 0.0), 1.0)
        best = max(best, v[a] + s_left * t - v[i])
    return float(min(max(best, 0.0), max(step, 0.0)))


def _extreme(arrays: list[np.ndarray], largest: bool) -> tuple[float, float]:
    """The largest (or smallest) value over run-ordered arrays, and how far the path may
    go beyond it between samples (:func:`_between_samples_um`)."""
    best, beyond = (-math.inf if largest else math.inf), 0.0
    for v in arrays:
        w = v if largest else -v
        i = int(np.argmax(w))
        if (v[i] > best) if largest else (v[i] < best):
            best, beyond = float(v[i]), _between_samples_um(w, i)
    return best, beyond


def _sampling(step_um: float, what: str) -> UncertaintyComponent:
    """The sampled extreme may miss the true one by up to ``step_um`` (one-sided), taken
    as rectangular of that full width: u = a/√3, so U = 1.15 a covers it."""
    if step_um == 0:
        return UncertaintyComponent("sampling", 0.0, "0: the readings beside the extreme equal it")
    return UncertaintyComponent("sampling", step_um / math.sqrt(3.0),
                                f"{what}: the path may pass up to {step_um:.3g} µm further between samples "
                                "(where the lines through the neighbouring readings meet), rectangular")


def _budget(quantity: str, *components: UncertaintyComponent) -> UncertaintyBudget:
    return UncertaintyBudget(quantity, tuple(components))


# ---------------------------------------------------------------- spikes

def _signed_after_deg(angle_deg: np.ndarray, quadrant_deg: float, direction: str) -> np.ndarray:
    """Angle travelled past the quadrant point in the pass' direction, in (-180, 180]."""
    sense = 1.0 if direction == "ccw" else -1.0
    s = (sense * (angle_deg - quadrant_deg) + 180.0) % 360.0 - 180.0
    return s


def _half_height_width(s: np.ndarray, v: np.ndarray, i_peak: int, level: float) -> float:
    """Width (deg) of the run of samples around ``i_peak`` (s sorted) above ``level``,
    each edge interpolated linearly to the crossing."""
    lo = i_peak
    while lo > 0 and v[lo - 1] >= level:
        lo -= 1
    hi = i_peak
    while hi < v.size - 1 and v[hi + 1] >= level:
        hi += 1

    def cross(i_in, i_out):
        if i_out < 0 or i_out >= v.size or v[i_in] == v[i_out]:
            return s[i_in]
        f = (v[i_in] - level) / (v[i_in] - v[i_out])
        return s[i_in] + f * (s[i_out] - s[i_in])

    return float(cross(hi, hi + 1) - cross(lo, lo - 1))


def _harmonics(angle_deg: np.ndarray) -> np.ndarray:
    th = np.deg2rad(angle_deg)
    return np.column_stack([np.ones_like(th), np.cos(th), np.sin(th), np.cos(2 * th), np.sin(2 * th)])


def _spikes(test: CircularTest, dev_by_pass: dict[str, np.ndarray], window_deg: float,
            sigma: dict[str, float]) -> tuple[list[Spike], dict[str, UncertaintyBudget], list[tuple[float, float]]]:
    """The spikes of every pass. The undisturbed path under a spike is the pass' own
    deviation on the arcs outside every window, fitted with the harmonics of order 0-2
    (its level, a centre shift and the ellipse unequal axis gains draw) and evaluated at
    the spike's angles. Also each pass' undisturbed level (the order-0 term: its radius
    about the least-squares centre minus the nominal radius) and its fit scatter, µm."""
    spikes, budgets, levels = [], {}, []
    for p in test.passes:
        dev = dev_by_pass[p.direction]
        after = {q: _signed_after_deg(p.angle_deg, q, p.direction) for q in QUADRANTS_DEG}
        undisturbed = np.zeros(dev.size, dtype=bool)
        for q in QUADRANTS_DEG:
            undisturbed |= (after[q] > window_deg) & (after[q] < 90.0)
        if undisturbed.sum() < 20:
            raise InputError(f"spike_window_deg (={window_deg}) leaves too few undisturbed samples between the "
                             "quadrants to take the circle's path from: use a smaller window")
        h = _harmonics(p.angle_deg)
        coef, *_ = np.linalg.lstsq(h[undisturbed], dev[undisturbed], rcond=None)
        level = h @ coef
        above = dev - level
        resid = above[undisturbed]
        n_base = int(undisturbed.sum())
        # the level under a spike: off by the undisturbed arcs' form beyond harmonics 0-2 (their
        # RMS departure less the noise), and by the fit's own scatter (σ √(5/n), five coefficients)
        sd = sigma[p.direction]
        form = math.sqrt(max(float(np.mean(resid**2)) - sd**2, 0.0))
        base_u = math.hypot(form, sd * math.sqrt(5.0 / n_base))
        levels.append((float(coef[0]), math.hypot(form, sd) / math.sqrt(n_base)))
        for q in QUADRANTS_DEG:
            s = after[q]
            near = (s > -45.0) & (s < 90.0)
            order = np.argsort(s[near])
            ss, vv = s[near][order], above[near][order]
            idx = np.flatnonzero((ss >= 0.0) & (ss <= window_deg))
            if not idx.size:  # pragma: no cover - the coverage check guarantees samples
                raise InputError(f"pass {p.direction!r}: no samples within {window_deg}° after {q:g}°")
            i_peak = int(idx[np.argmax(vv[idx])])
            height = float(vv[i_peak])
            step = _between_samples_um(vv, i_peak)
            width = _half_height_width(ss, vv, i_peak, height / 2.0) if height > 0 else 0.0
            n_top = int(np.sum(vv[idx] >= vv[i_peak] - 3.0 * sd)) if sd > 0 else 1
            axis = test.plane[0] if q in (0.0, 180.0) else test.plane[1]
            budget = _budget(
                f"spike.{p.direction}.{q:g}",
                _resolution(test, 1.0, "the peak reading (the undisturbed path is fitted to many)"),
                _noise(sd, _extremes_factor(n_top),
                       f"the peak of {n_top} readings within 3σ of it reads high by up to σ√(2 ln n)"),
                UncertaintyComponent(
                    "baseline", base_u,
                    f"the undisturbed path under the spike: form of the {n_base} undisturbed readings beyond "
                    f"harmonics 0-2 ({form:.3g} µm RMS) and the fit's scatter" if base_u > 0
                    else "0: the undisturbed arcs lie on their fitted path"),
                _accuracy(test, math.sqrt(2.0), "peak and undisturbed path, two readings"),
                _sampling(step, "the peak"),
            )
            budgets[budget.quantity] = budget
            peak_deg = float((q + (1.0 if p.direction == "ccw" else -1.0) * ss[i_peak]) % 360.0)
            spikes.append(Spike(axis=axis, quadrant_deg=q, direction=p.direction, height_um=height,
                                height_uncertainty_um=budget.expanded_um, width_deg=width, peak_deg=peak_deg))
    return spikes, budgets, levels


# ---------------------------------------------------------------- hysteresis

def _hysteresis_um(a: CirclePass, dev_a: np.ndarray, b: CirclePass, dev_b: np.ndarray) -> tuple[float, float]:
    """Largest |d_ccw - d_cw| at the same angle (each pass' samples against the other pass
    interpolated linearly in angle, periodic), and the step beside it along the run."""
    diffs = []
    for p, dp, o, do in ((a, dev_a, b, dev_b), (b, dev_b, a, dev_a)):
        order = np.argsort(o.angle_deg, kind="stable")
        other = np.interp(p.angle_deg, o.angle_deg[order], do[order], period=360.0)
        diffs.append(np.abs(dp - other))
    return _extreme(diffs, largest=True)


# ---------------------------------------------------------------- analysis

def analyze(test: CircularTest, *, spike_window_deg: float = DEFAULT_SPIKE_WINDOW_DEG) -> CircleFigures:
    """ISO 230-4's figures of ``test`` with their uncertainty (see the module docstring).

    ``spike_window_deg``: how far past each quadrant point (in the direction of travel)
    the reversal spike is looked for; the rest of each quadrant is the undisturbed arc.
    """
    if not isinstance(test, CircularTest):
        raise InputError(f"analyze needs a CircularTest, got {type(test).__name__}")
    w = float(spike_window_deg)
    if not (math.isfinite(w) and 1.0 <= w <= 80.0):
        raise InputError(f"spike_window_deg (={spike_window_deg}) must be within 1..80°")
    r_um = test.radius_mm * 1e3
    pts = {p.direction: points_um(p, r_um) for p in test.passes}
    x = np.concatenate([pts[d][0] for d in test.directions])
    y = np.concatenate([pts[d][1] for d in test.directions])
    n = x.size
    centre, r_fit = _lsq_circle(x, y, r_um)
    dev = {d: deviation_um(*pts[d], centre, r_um) for d in test.directions}
    dev_all = np.concatenate([dev[d] for d in test.directions])
    hi, step_hi = _extreme([dev[d] for d in test.directions], largest=True)
    lo, step_lo = _extreme([dev[d] for d in test.directions], largest=False)
    g_lsq = hi - lo
    g_mz, mz_centre, mz_solved = _min_zone(x, y, centre, r_um)
    g_mz = min(g_mz, g_lsq)

    sigma = {p.direction: _noise_um(p) for p in test.passes}
    sig = max(sigma.values())
    res_rms = float(np.sqrt(np.mean((dev_all - (r_fit - r_um)) ** 2)))

    per_direction = {}
    for p in test.passes:
        c, _ = _lsq_circle(*pts[p.direction], r_um)
        dv = deviation_um(*pts[p.direction], c, r_um)
        g1 = float(dv.max() - dv.min())
        g1_mz, _, _ = _min_zone(*pts[p.direction], c, r_um)
        per_direction[p.direction] = {"circular_deviation_um": g1, "circular_deviation_mz_um": min(g1_mz, g1),
                                      "centre_offset_um": [float(c[0]), float(c[1])], "noise_um": sigma[p.direction]}

    budgets = {}
    budgets["circular_deviation"] = _budget(
        "circular_deviation",
        _resolution(test, math.sqrt(2.0), "two readings (largest and smallest)"),
        _noise(sig, math.sqrt(2.0) * _extremes_factor(n), f"the extremes of {n} readings, √2·σ·√(2 ln N)"),
        _accuracy(test, math.sqrt(2.0), "two readings"),
        _sampling(math.hypot(step_hi, step_lo), "largest and smallest reading"),
    )
    f_hi, f_step_hi = _extreme([p.radial_um for p in test.passes], largest=True)
    f_lo, f_step_lo = _extreme([p.radial_um for p in test.passes], largest=False)
    budgets["radial_deviation"] = _budget(
        "radial_deviation",
        _resolution(test, 1.0, "one reading"),
        _noise(sig, _extremes_factor(n), f"the extreme of {n} readings, σ·√(2 ln N)"),
        _accuracy(test, 1.0, "one reading against the nominal radius"),
        _sampling(max(f_step_hi, f_step_lo), "F max or F min"),
    )
    fit_note = f"residual RMS {res_rms:.3g} µm over {n} readings (form errors counted as scatter)"
    budgets["centre_offset"] = _budget(
        "centre_offset",
        UncertaintyComponent("fit", res_rms * math.sqrt(2.0 / n), fit_note + ", √(2/N) per axis"),
        _accuracy(test, 1.0, "the instrument's reading of where the circle lies"),
    )
    budgets["mean_radius_deviation"] = _budget(
        "mean_radius_deviation",
        UncertaintyComponent("fit", res_rms / math.sqrt(n), fit_note + ", √(1/N)"),
        _accuracy(test, 1.0, "the absolute radius"),
    )
    hyst = hyst_u = None
    if len(test.passes) == 2:
        a, b = test.passes
        hyst, h_step = _hysteresis_um(a, dev[a.direction], b, dev[b.direction])
        budgets["hysteresis"] = _budget(
            "hysteresis",
            _resolution(test, math.sqrt(2.0), "one reading of each direction"),
            _noise(math.hypot(sigma[a.direction], sigma[b.direction]) / math.sqrt(2.0),
                   math.sqrt(2.0) * _extremes_factor(n), "the largest of N differences, √2·σ·√(2 ln N)"),
            _accuracy(test, 0.0, "both directions are read at the same angle by the same instrument; its "
                                 "calibration error cancels in the difference"),
            _sampling(h_step, "the largest difference"),
        )
        hyst_u = budgets["hysteresis"].expanded_um

    spikes, spike_budgets, levels = _spikes(test, dev, w, sigma)
    budgets.update(spike_budgets)
    budgets["undisturbed_radius_deviation"] = _budget(
        "undisturbed_radius_deviation",
        UncertaintyComponent("fit", math.hypot(res_rms / math.sqrt(n), math.sqrt(sum(u * u for _, u in levels))
                                               / len(levels)),
                             "the least-squares radius and the undisturbed arcs' level about it"),
        _accuracy(test, 1.0, "the absolute radius"),
    )
    return CircleFigures(
        radius_mm=test.radius_mm,
        feed_mm_min=test.feed_mm_min,
        plane=test.plane,
        circular_deviation_um=g_lsq,
        circular_deviation_mz_um=g_mz,
        circular_deviation_uncertainty_um=budgets["circular_deviation"].expanded_um,
        hysteresis_um=hyst,
        hysteresis_uncertainty_um=hyst_u,
        radial_deviation_max_um=f_hi,
        radial_deviation_min_um=f_lo,
        radial_deviation_uncertainty_um=budgets["radial_deviation"].expanded_um,
        centre_offset_um=(float(centre[0]), float(centre[1])),
        centre_offset_uncertainty_um=budgets["centre_offset"].expanded_um,
        mean_radius_deviation_um=float(r_fit - r_um),
        spikes=tuple(spikes),
        per_direction=per_direction,
        mean_radius_deviation_uncertainty_um=budgets["mean_radius_deviation"].expanded_um,
        undisturbed_radius_deviation_um=float(np.mean([c for c, _ in levels])),
        undisturbed_radius_deviation_uncertainty_um=budgets["undisturbed_radius_deviation"].expanded_um,
        centre_offset_mz_um=(float(mz_centre[0]), float(mz_centre[1])),
        spike_window_deg=w,
        noise_um=sig,
        directions=test.directions,
        minimum_zone_note="" if mz_solved else ("the minimum-zone programme did not solve: the minimum-zone G "
                                                "shown is the best centre found, at most the least-squares G"),
        budgets=budgets,
    )


__all__ = ["DEFAULT_SPIKE_WINDOW_DEG", "DIRECTIONS", "CircleFigures", "Spike", "analyze"]
