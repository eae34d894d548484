"""The two loops side by side: the reversal spikes a circular test measures against the
TBE Eq. 8 predicts from the axis' backlash b̄ (the indirect loop), and, away from the
reversals, the circle against the one Eq. 8's proportional loop traces (:func:`loop_check`).

Both are the same quantity: the radial deviation after a quadrant point from the path
the loop traces without backlash (Eq. 8 is written relative to the circle of radius
R cos φ; a spike's height is taken above the undisturbed path of the test). They agree
when the normalised error E_n = (measured - predicted) / √(U_m² + U_p²) (ISO 13528,
expanded uncertainties, k = 2) has |E_n| <= 1.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np

from core.circle.figures import CircleFigures
from core.errors import InputError, ModelDomainError, require_finite
from core.tbe.decision import MachiningTask
from core.tbe.formulas import circle_steady_lag_um

VERDICTS = ("agree", "larger", "smaller")
# Eq. 8 against an exact time-domain simulation of its own model (rigid backlash, ideal
# inner loops, P position loop): within 0.2 % over b 20-300 µm, R 25-200 mm, feed
# 100-3000 mm/min, K 10-30 1/s (docs/metrology.md); taken as a rectangular half-width.
EQ8_MODEL_REL = 0.002
# The slowest servo period of a position loop in common use (LinuxCNC's servo thread
# default; drives close theirs at 62.5-250 µs): the bound of the sampled loop's departure
# from the continuous one Eq. 8 is written for, in the loop check.
SERVO_PERIOD_MAX_S = 1e-3

MEANINGS = {
    "agree": ("the spikes are what the backlash explains: the encoders' lost motion and the contour tell "
              "the same story"),
    "larger": ("the spikes are larger than the backlash explains: look at friction (stick-slip at the reversal) "
               "or the servo (gain, velocity loop, dead time), and run the gap diagnosis on these runs"),
    "smaller": ("the spikes are smaller than the backlash predicts: the chain has less play than the encoders' "
                "lost motion says (part of it is elastic wind-up or the scales' own hysteresis), or the drive "
                "compensates the reversal (backlash compensation, reversal spike compensation)"),
}


LOOP_MEANINGS = {
    "agree": "away from the reversals the circle is the one the paper's proportional loop at K traces",
    "larger": ("away from the reversals the circle is larger than a proportional loop at K traces: the drive "
               "feeds the commanded velocity forward, or its gain is above K. The spikes above that path are "
               "still Eq. 8's, but against the programmed circle the error at a reversal is the spike itself, "
               "no longer the spike less the loop's lag R (1 - cos φ)"),
    "smaller": ("away from the reversals the circle is smaller than a proportional loop at K traces: the loop's "
                "effective gain is below K or its velocity loop lags; give the axis its effective gain, or run "
                "the gap diagnosis (servo dynamics)"),
}


@dataclass(frozen=True)
class Agreement:
    """Eq. 8 at b̄ against the measured spikes of ``axis``; uncertainties expanded (k = 2)."""

    axis: str
    predicted_um: float
    predicted_uncertainty_um: float
    measured_um: float
    measured_uncertainty_um: float
    normalised_error: float
    agree: bool
    verdict: str
    meaning: str
    backlash_um: float = 0.0
    backlash_uncertainty_um: float = 0.0
    gain_per_s: float = 0.0
    radius_mm: float = 0.0
    feed_mm_min: float = 0.0
    spikes: tuple[str, ...] = ()  # the reversals measured, "<direction>@<quadrant>°"
    # the loop Eq. 8 assumes, checked where nothing reverses: the undisturbed circle's radius
    # deviation against a proportional loop's -R (1 - cos φ) (None: not checked)
    loop: LoopCheck | None = None

    def sentence(self) -> str:
        text = (f"axis {self.axis}: spikes {self.measured_um:.2f} ± {self.measured_uncertainty_um:.2f} µm, Eq. 8 at "
                f"b̄ {self.backlash_um:.1f} ± {self.backlash_uncertainty_um:.1f} µm predicts "
                f"{self.predicted_um:.2f} ± {self.predicted_uncertainty_um:.2f} µm (k = 2), "
                f"E_n {self.normalised_error:+.2f}: {self.meaning}")
        if self.loop is not None and self.loop.verdict != "agree":
            text += f". {self.loop.sentence()}"
        return text

    def to_dict(self) -> dict:
        return {
            "axis": self.axis,
            "predicted_um": self.predicted_um,
            "predicted_uncertainty_um": self.predicted_uncertainty_um,
            "measured_um": self.measured_um,
            "measured_uncertainty_um": self.measured_uncertainty_um,
            "normalised_error": self.normalised_error,
            "agree": self.agree,
            "verdict": self.verdict,
            "meaning": self.meaning,
            "backlash_um": self.backlash_um,
            "backlash_uncertainty_um": self.backlash_uncertainty_um,
            "gain_per_s": self.gain_per_s,
            "radius_mm": self.radius_mm,
            "feed_mm_min": self.feed_mm_min,
            "spikes": list(self.spikes),
            "coverage_factor": 2.0,
            "loop": None if self.loop is None else self.loop.to_dict(),
        }


@dataclass(frozen=True)
class LoopCheck:
    """The undisturbed circle against the one a proportional loop at K traces (Eq. 8's
    loop): radius deviations from the nominal radius, expanded uncertainties (k = 2)."""

    predicted_um: float
    predicted_uncertainty_um: float
    measured_um: float
    measured_uncertainty_um: float
    normalised_error: float
    verdict: str
    meaning: str

    def sentence(self) -> str:
        return (f"The undisturbed circle is {self.measured_um:+.2f} ± {self.measured_uncertainty_um:.2f} µm off the "
                f"nominal radius, a proportional loop at K traces {self.predicted_um:+.2f} ± "
                f"{self.predicted_uncertainty_um:.2f} µm (E_n {self.normalised_error:+.2f}): {self.meaning}")

    def to_dict(self) -> dict:
        return {"predicted_um": self.predicted_um, "predicted_uncertainty_um": self.predicted_uncertainty_um,
                "measured_um": self.measured_um, "measured_uncertainty_um": self.measured_uncertainty_um,
                "normalised_error": self.normalised_error, "verdict": self.verdict, "meaning": self.meaning}


def _normalised(diff: float, u_a: float, u_b: float) -> tuple[float, str]:
    denom = math.hypot(u_a, u_b)
    en = diff / denom if denom > 0 else (0.0 if diff == 0 else math.copysign(math.inf, diff))
    return en, "agree" if abs(en) <= 1.0 else ("larger" if en > 0 else "smaller")


def loop_check(figures: CircleFigures, *, gain_per_s: float, gain_rel_uncertainty: float = 0.01) -> LoopCheck | None:
    """The undisturbed circle's radius deviation (away from the reversals) against the
    proportional loop's -R (1 - cos φ), tan φ = ω / K, K known within ``gain_rel_uncertainty``
    (a rectangular half-width), the loop sampled at up to SERVO_PERIOD_MAX_S. Eq. 8 is
    written for that loop; a drive that feeds the velocity forward traces the full radius
    and still shows Eq. 8's spikes above it. None where the test has no undisturbed level."""
    measured = figures.undisturbed_radius_deviation_um
    u_m = figures.undisturbed_radius_deviation_uncertainty_um
    if not (math.isfinite(measured) and math.isfinite(u_m)):
        return None
    k = require_finite("gain_per_s", gain_per_s)
    lag = circle_steady_lag_um(figures.radius_mm, figures.feed_mm_min, k)
    r_mm, feed = figures.radius_mm, figures.feed_mm_min
    spread = [abs(circle_steady_lag_um(r_mm, feed, k * (1 + d * gain_rel_uncertainty)) - lag) for d in (1.0, -1.0)]
    # a real loop is sampled: at a servo period T it passes the circle with the gain
    # KT / |e^(jωT) - 1 + KT| instead of K / |jω + K|, a circle about R ω² T / 2K larger
    # (0.9 µm at R 20 mm, 2000 mm/min, K 30/s, T 1 ms); T up to SERVO_PERIOD_MAX_S, rectangular
    w = figures.feed_mm_min / 60.0 / figures.radius_mm
    kt = k * SERVO_PERIOD_MAX_S
    sampled = kt / abs(np.exp(1j * w * SERVO_PERIOD_MAX_S) - 1.0 + kt)
    servo = abs(sampled - k / math.hypot(w, k)) * figures.radius_mm * 1e3
    u_p = 2.0 * math.hypot(max(spread), servo) / math.sqrt(3.0)
    en, verdict = _normalised(measured + lag, u_m, u_p)
    return LoopCheck(predicted_um=-lag, predicted_uncertainty_um=u_p, measured_um=measured, measured_uncertainty_um=u_m,
                     normalised_error=en, verdict=verdict, meaning=LOOP_MEANINGS[verdict])


def measured_spike_um(figures: CircleFigures, axis: str) -> tuple[float, float, tuple[str, ...]]:
    """The mean height of ``axis``' spikes (every reversal of it, both directions) and its
    expanded uncertainty: the spikes' mean U (their components are shared: instrument,
    undisturbed path) combined with the scatter of the mean, 2 s/√n."""
    spikes = figures.spikes_of(axis)
    if not spikes:
        raise InputError(f"axis (={axis!r}) does not reverse in this circular test (its plane is "
                         f"{figures.plane}): give one of its two axes")
    h = np.array([s.height_um for s in spikes])
    u = np.array([s.height_uncertainty_um for s in spikes])
    scatter = 2.0 * float(np.std(h, ddof=1)) / math.sqrt(h.size) if h.size > 1 else 0.0
    names = tuple(f"{s.direction}@{s.quadrant_deg:g}°" for s in spikes)
    return float(h.mean()), math.hypot(float(u.mean()), scatter), names


def predicted_tbe_um(backlash_um: float, backlash_uncertainty_um: float, *, radius_mm: float, feed_mm_min: float,
                     gain_per_s: float, gain_rel_uncertainty: float = 0.01) -> tuple[float, float]:
    """Eq. 8 at b̄ and its expanded uncertainty: b̄'s U through the slope of Eq. 8 (as
    :meth:`MachiningTask.tbe_uncertainty_um`), the gain's (``gain_rel_uncertainty`` a
    rectangular half-width on K: the TBE at K (1 ± δ)) and Eq. 8's own accuracy
    against the exact model (``EQ8_MODEL_REL``, rectangular)."""
    b = require_finite("backlash_um", backlash_um)
    u_b = require_finite("backlash_uncertainty_um", backlash_uncertainty_um)
    if b < 0 or u_b < 0:
        raise InputError(f"backlash_um (={b}) and backlash_uncertainty_um (={u_b}) must be >= 0")
    task = MachiningTask("circular test", profile="circle", radius_mm=radius_mm, feed_mm_min=feed_mm_min,
                         gain_per_s=gain_per_s, tolerance_um=1.0, gain_rel_uncertainty=gain_rel_uncertainty)
    try:
        tbe = float(task.tbe_um(b))
    except ModelDomainError as exc:
        raise ModelDomainError(f"Eq. 8 cannot predict the spikes of this test: {exc}") from exc
    u_from_b = task.tbe_uncertainty_um(b, u_b)
    half = []
    for sign in (1.0, -1.0):
        try:
            half.append(abs(float(replace(task, gain_per_s=gain_per_s * (1 + sign * gain_rel_uncertainty))
                                  .tbe_um(b)) - tbe))
        except ModelDomainError:
            continue
    u_from_k = 2.0 * max(half, default=0.0) / math.sqrt(3.0)
    u_model = 2.0 * EQ8_MODEL_REL * tbe / math.sqrt(3.0)
    return tbe, math.sqrt(u_from_b**2 + u_from_k**2 + u_model**2)


def compare_with_backlash(figures: CircleFigures, *, axis: str, backlash_um: float, backlash_uncertainty_um: float,
                          gain_per_s: float, gain_rel_uncertainty: float = 0.01) -> Agreement:
    """Eq. 8 at the axis' latest b̄ (U carried through), at the test's radius and feed and
    the axis' gain, against the measured spikes of the quadrants where ``axis`` reverses."""
    if not isinstance(figures, CircleFigures):
        raise InputError(f"compare_with_backlash needs CircleFigures (from analyze), got {type(figures).__name__}")
    axis = str(axis).strip().lower()
    measured, u_m, names = measured_spike_um(figures, axis)
    predicted, u_p = predicted_tbe_um(backlash_um, backlash_uncertainty_um, radius_mm=figures.radius_mm,
                                      feed_mm_min=figures.feed_mm_min, gain_per_s=gain_per_s,
                                      gain_rel_uncertainty=gain_rel_uncertainty)
    en, verdict = _normalised(measured - predicted, u_m, u_p)
    return Agreement(axis=axis, predicted_um=predicted, predicted_uncertainty_um=u_p, measured_um=measured,
                     measured_uncertainty_um=u_m, normalised_error=en, agree=verdict == "agree", verdict=verdict,
                     meaning=MEANINGS[verdict], backlash_um=float(backlash_um),
                     backlash_uncertainty_um=float(backlash_uncertainty_um), gain_per_s=float(gain_per_s),
                     radius_mm=figures.radius_mm, feed_mm_min=figures.feed_mm_min, spikes=names,
                     loop=loop_check(figures, gain_per_s=gain_per_s, gain_rel_uncertainty=gain_rel_uncertainty))
