"""Single-sample glitches and short bursts on the encoders: one rule for files and online.

The rule is a Hampel identifier: a sample is an outlier when it lies further from the
median of its window than ``n_sigmas`` robust standard deviations, the larger of the
window's own (1.4826 MAD) and the whole signal's noise (from the MAD of its second
differences), and never closer than ``floor_um``. It is applied to

- the motor-table difference l_a - l_0 (a glitch of either encoder shows there), and
- each encoder's own position, detrended by the window's median velocity, so that a
  glitch is told apart from the motion (its *smoothness*).

A median of 7 samples survives a burst of up to 3. A rolling median over a million
samples costs more than the rest of the analysis, so the Hampel test runs only around
candidates: on the difference, samples whose step exceeds ¾ of the global threshold
(every glitch or burst steps by its size at its edge, so none is missed); on an
encoder, samples further than that from their neighbours' midpoint (a single glitch
always; a burst of 2-3 only when it is 1.5x the threshold; the difference catches the
smaller ones of one encoder).

``acquisition``'s online ``EncoderMonitor`` calls :func:`encoder_outliers` on the same
settings, so a glitch the file path would drop is not a fault online either.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from core.errors import InputError, OutlierError

_MAD_TO_SIGMA = 1.4826
_SUBSAMPLE = 20_000  # the global noise scale is a median: a strided subsample is enough (MAD ±1 %)


@dataclass(frozen=True)
class OutlierSettings:
    """``window_samples`` (odd) of the Hampel identifier; ``n_sigmas`` its threshold;
    ``floor_um`` the smallest deviation ever called an outlier (an exact, noise-free
    trace has no scale); ``max_fraction`` of a stroke's samples beyond which the trace
    is refused (:class:`OutlierError`) rather than cleaned; ``enabled`` False skips it."""

    window_samples: int = 7
    n_sigmas: float = 6.0
    floor_um: float = 2.0
    max_fraction: float = 0.01
    enabled: bool = True

    def __post_init__(self) -> None:
        if self.window_samples < 3 or self.window_samples % 2 == 0:
            raise InputError(f"window_samples (={self.window_samples}) must be an odd number >= 3")
        if not self.n_sigmas > 0:
            raise InputError(f"n_sigmas (={self.n_sigmas}) must be > 0")
        if not self.floor_um >= 0:
            raise InputError(f"floor_um (={self.floor_um}) must be >= 0")
        if not 0.0 <= self.max_fraction <= 1.0:
            raise InputError(f"max_fraction (={self.max_fraction}) must be in [0, 1]")


def noise_sigma_mm(values_mm: np.ndarray) -> float:
    """Robust standard deviation (mm) of white noise on a smooth signal, from the MAD
    of its second differences (variance 6 σ² for white noise). Signal curvature between
    samples adds to it, so on sparse traces it errs on the large side."""
    v = np.asarray(values_mm, dtype=float)
    if v.size < 3:
        return 0.0
    stride = max(1, (v.size - 2) // _SUBSAMPLE)
    d2 = v[2::stride] - 2.0 * v[1:-1:stride] + v[:-2:stride]  # at every stride-th sample only
    return float(_MAD_TO_SIGMA * np.median(np.abs(d2 - np.median(d2))) / np.sqrt(6.0))


def hampel_mask(values_mm: np.ndarray, settings: OutlierSettings = OutlierSettings(), *,
                detrend: bool = False, noise_mm: float | None = None, time_s: np.ndarray | None = None,
                clock_uncertainty_s: float = 0.0) -> np.ndarray:
    """Boolean mask of the outliers of one contiguous signal (mm).

    ``detrend``: compare each sample with the window's median after removing the
    window's median velocity (for an encoder's position while the axis moves), per
    unit of ``time_s`` when given (polled or decimated samples are irregular), else
    per sample. ``noise_mm``: the global noise scale, estimated when not given.
    ``clock_uncertainty_s``: a bound on the error of each ``time_s`` (a polled sample is
    stamped at the middle of its request, not when the controller latched it): a sample
    moved along the motion by up to 2 |v| u from its neighbours' line is not told apart
    from a stamp error, so it is not called an outlier.
    """
    v = np.asarray(values_mm, dtype=float)
    n = v.size
    mask = np.zeros(n, dtype=bool)
    if n < 3 or not settings.enabled:
        return mask
    sigma = noise_sigma_mm(v) if noise_mm is None else float(noise_mm)
    thr_global = max(settings.n_sigmas * sigma, settings.floor_um * 1e-3)
    t = None if time_s is None else np.asarray(time_s, dtype=float)
    if t is not None and t.shape != v.shape:
        raise InputError(f"time_s and the values differ in length: {t.size}, {v.size}")
    if detrend and t is not None:
        # distance from the line through the neighbours: a glitch G stands out by G, the motion not
        w = (t[1:-1] - t[:-2]) / (t[2:] - t[:-2])
        step = np.abs(v[1:-1] - (v[:-2] + w * (v[2:] - v[:-2])))
    elif detrend:
        # distance from the neighbours' midpoint: a glitch G stands out by G, the motion not
        step = np.abs(v[1:-1] - 0.5 * (v[2:] + v[:-2]))
    else:
        step = np.abs(np.diff(v))  # a glitch or a burst steps by G at its edges
    cand = np.flatnonzero(step > 0.75 * thr_global) + 1
    if cand.size == 0:
        return mask
    h = settings.window_samples // 2
    offsets = np.arange(-h, h + 1)
    near = np.zeros(n, dtype=bool)
    for o in offsets:
        near[np.clip(cand + o, 0, n - 1)] = True
    test = np.flatnonzero(near)
    idx = np.clip(test[:, None] + offsets, 0, n - 1)
    win = v[idx]
    if detrend and t is not None:
        tw = t[idx]
        dt = np.diff(tw, axis=1)
        with np.errstate(divide="ignore", invalid="ignore"):
            vel = np.nanmedian(np.where(dt > 0, np.diff(win, axis=1) / np.where(dt > 0, dt, 1.0), np.nan), axis=1)
        vel = np.nan_to_num(vel)
        win = win - (tw - tw[:, h : h + 1]) * vel[:, None]  # each window's values brought to its centre
    elif detrend:
        vel = np.median(np.diff(win, axis=1), axis=1)
        win = win - offsets[None, :] * vel[:, None]
    ref = np.median(win, axis=1)
    mad = np.median(np.abs(win - ref[:, None]), axis=1)
    thr = np.maximum(settings.n_sigmas * _MAD_TO_SIGMA * mad, thr_global)
    if detrend and t is not None and clock_uncertainty_s > 0:
        thr = thr + 2.0 * np.abs(vel) * clock_uncertainty_s
    centre = win[:, h]
    mask[test[np.abs(centre - ref) > thr]] = True
    return mask


def encoder_outliers(motor_mm: np.ndarray, table_mm: np.ndarray,
                     settings: OutlierSettings = OutlierSettings(), *, time_s: np.ndarray | None = None,
                     sampling_bound_um: float = 0.0, clock_uncertainty_s: float = 0.0) -> np.ndarray:
    """Outliers of one contiguous stretch of motion: on the motor-table difference and
    on each encoder's smoothness. ``motor_mm`` is the motor position as table travel
    (k_a x_m); ``time_s`` (or any clock, e.g. a servo-cycle counter) the sampling
    instants when they are irregular. ``sampling_bound_um``: the known scatter of the
    readings from sampling (skew x speed when the encoders are read separately); no
    deviation within twice that is called an outlier. ``clock_uncertainty_s``: a bound
    on the error of each ``time_s`` (polled samples), for the smoothness tests only: the
    motor-table difference of a latched pair does not depend on when it was latched.
    Returns a boolean mask."""
    m = np.asarray(motor_mm, dtype=float)
    t = np.asarray(table_mm, dtype=float)
    if m.shape != t.shape:
        raise InputError(f"motor_mm and table_mm differ in length: {m.size}, {t.size}")
    if not settings.enabled:
        return np.zeros(m.size, dtype=bool)
    if sampling_bound_um > 0:
        settings = replace(settings, floor_um=max(settings.floor_um, 2.0 * sampling_bound_um))
    return (
        hampel_mask(t - m, settings)
        | hampel_mask(m, settings, detrend=True, time_s=time_s, clock_uncertainty_s=clock_uncertainty_s)
        | hampel_mask(t, settings, detrend=True, time_s=time_s, clock_uncertainty_s=clock_uncertainty_s)
    )


def check_outlier_fraction(n_outliers: int, n_samples: int, settings: OutlierSettings, where: str) -> None:
    """Raise :class:`OutlierError` when more than ``max_fraction`` of the samples are outliers."""
    if n_samples and n_outliers > settings.max_fraction * n_samples:
        raise OutlierError(
            f"{n_outliers} of {n_samples} samples {where} are outliers "
            f"({100.0 * n_outliers / n_samples:.2f} % > max_fraction {100.0 * settings.max_fraction:g} %): "
            f"a faulty encoder, reading head or cable?"
        )
