"""A circular test (ISO 230-4): two axes of a plane run a full circle, in one or both
directions, and an instrument reads the radial deviation along it.

The data types every part of mebm exchanges (acquisition, import, storage, analysis),
and their validation. Angles are degrees from the + first-axis direction,
counter-clockwise positive, in [0, 360); radial deviations are the measured radius
minus the nominal radius about the nominal centre, in µm.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from core.errors import InputError, require_finite, require_positive

DIRECTIONS = ("ccw", "cw")
INSTRUMENT_KINDS = ("encoders", "ballbar", "trace")
QUADRANTS_DEG = (0.0, 90.0, 180.0, 270.0)
MIN_SAMPLES = 72  # per pass: at least one sample every 5° on average
MAX_GAP_DEG = 5.0  # the widest angular gap a pass may leave (a narrower spike could hide in it)
MAX_RADIAL_FRACTION = 0.1  # |radial deviation| beyond 10 % of the radius is a unit or centre mistake


@dataclass(frozen=True)
class Instrument:
    """What measured the circle, and its budget (all standard uncertainties, k = 1, µm).

    ``kind``: ``"encoders"`` (the CNC's own scales), ``"ballbar"`` or ``"trace"`` (a
    controller's trace tool). ``resolution_um``: the quantisation step of the radial
    reading (u = q/√12; 0 for an interpolated or simulated reading).
    ``accuracy_um``: the calibration/accuracy of the radial reading, as a standard
    uncertainty (a ballbar's calibrator, the scales' accuracy over the circle).
    """

    kind: str
    resolution_um: float
    accuracy_um: float = 0.0
    name: str = ""

    def __post_init__(self) -> None:
        if self.kind not in INSTRUMENT_KINDS:
            raise InputError(f"instrument.kind (={self.kind!r}) must be one of {INSTRUMENT_KINDS}")
        for key in ("resolution_um", "accuracy_um"):
            v = getattr(self, key)
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v) or v < 0:
                raise InputError(f"instrument.{key} (={v!r}) must be a finite number >= 0")
            object.__setattr__(self, key, float(v))
        if not isinstance(self.name, str):
            raise InputError(f"instrument.name (={self.name!r}) must be text")


@dataclass(frozen=True, eq=False)
class CirclePass:
    """One direction of a circular test: the radial deviation per angle.

    ``angle_deg``: angle of each sample from the + first-axis direction, ccw positive,
    in [0, 360) (not unwrapped), in the order the machine ran them. ``radial_um``:
    measured radius minus the nominal radius, µm, about the nominal centre.
    """

    direction: str
    angle_deg: np.ndarray
    radial_um: np.ndarray

    def __post_init__(self) -> None:
        if self.direction not in DIRECTIONS:
            raise InputError(f"pass direction (={self.direction!r}) must be one of {DIRECTIONS}")
        where = f"pass {self.direction!r}"
        ang = _array(f"{where}: angle_deg", self.angle_deg)
        rad = _array(f"{where}: radial_um", self.radial_um)
        if ang.shape != rad.shape:
            raise InputError(f"{where}: angle_deg ({ang.size} samples) and radial_um ({rad.size}) must be "
                             "of equal length")
        if ang.size < MIN_SAMPLES:
            raise InputError(f"{where}: {ang.size} samples; a circular test needs at least {MIN_SAMPLES} per "
                             "direction (one every 5°): record at a higher rate or a lower feed")
        if np.any(ang < 0.0) or np.any(ang >= 360.0):
            raise InputError(f"{where}: angle_deg must be in [0, 360) (found {ang.min():.6g}..{ang.max():.6g})")
        ang.setflags(write=False)
        rad.setflags(write=False)
        object.__setattr__(self, "angle_deg", ang)
        object.__setattr__(self, "radial_um", rad)
        _check_coverage(where, ang)
        _check_sense(where, self.direction, ang)

    def __eq__(self, other) -> bool:
        if not isinstance(other, CirclePass):
            return NotImplemented
        return (self.direction == other.direction and np.array_equal(self.angle_deg, other.angle_deg)
                and np.array_equal(self.radial_um, other.radial_um))

    __hash__ = None  # holds arrays

    @property
    def unwrapped_deg(self) -> np.ndarray:
        """The angles unwrapped along the run (continuous, increasing for ccw)."""
        return np.rad2deg(np.unwrap(np.deg2rad(self.angle_deg)))


@dataclass(frozen=True)
class CircularTest:
    """A circular test at ``radius_mm`` and ``feed_mm_min`` in ``plane`` (first axis at 0°),
    one pass per direction, read with ``instrument``. ``source`` says where it came from
    ("measured: linuxcnc://...", "imported: file.csv", "simulated: ...")."""

    radius_mm: float
    feed_mm_min: float
    plane: tuple[str, str]
    passes: tuple[CirclePass, ...]
    instrument: Instrument
    temperature_c: float | None = None
    utility_day: float | None = None
    source: str = ""

    def __post_init__(self) -> None:
        r = require_positive("radius_mm", self.radius_mm)
        object.__setattr__(self, "radius_mm", r)
        object.__setattr__(self, "feed_mm_min", require_positive("feed_mm_min", self.feed_mm_min))
        plane = tuple(self.plane) if isinstance(self.plane, (tuple, list)) else ()
        if len(plane) != 2 or not all(isinstance(a, str) and a.strip() for a in plane):
            raise InputError(f"plane (={self.plane!r}) must name two axes, e.g. ('x', 'y')")
        plane = tuple(a.strip().lower() for a in plane)
        if plane[0] == plane[1]:
            raise InputError(f"plane (={self.plane!r}) must name two different axes")
        object.__setattr__(self, "plane", plane)
        passes = tuple(self.passes) if isinstance(self.passes, (tuple, list)) else (self.passes,)
        if not passes:
            raise InputError("passes: a circular test needs at least one direction (ccw and/or cw)")
        if not all(isinstance(p, CirclePass) for p in passes):
            raise InputError("passes must be CirclePass objects")
        dirs = [p.direction for p in passes]
        if len(set(dirs)) != len(dirs):
            raise InputError(f"passes: direction {dirs} repeated; give one pass per direction")
        object.__setattr__(self, "passes", tuple(sorted(passes, key=lambda p: DIRECTIONS.index(p.direction))))
        if not isinstance(self.instrument, Instrument):
            raise InputError("instrument must be an Instrument (kind, resolution_um, accuracy_um)")
        limit_um = MAX_RADIAL_FRACTION * r * 1e3
        for p in passes:
            worst = float(np.max(np.abs(p.radial_um)))
            if worst > limit_um:
                raise InputError(
                    f"pass {p.direction!r}: a radial deviation of {worst:.6g} µm is beyond 10 % of radius_mm "
                    f"(={r}): radial_um must be in µm, about the nominal centre and radius")
        for key in ("temperature_c", "utility_day"):
            v = getattr(self, key)
            if v is not None:
                object.__setattr__(self, key, require_finite(key, v))
        if not isinstance(self.source, str):
            raise InputError(f"source (={self.source!r}) must be text")

    @property
    def directions(self) -> tuple[str, ...]:
        return tuple(p.direction for p in self.passes)

    def pass_of(self, direction: str) -> CirclePass:
        for p in self.passes:
            if p.direction == direction:
                return p
        raise InputError(f"the test has no {direction!r} pass (it has {self.directions})")


def _array(name: str, values) -> np.ndarray:
    try:
        a = np.array(values, dtype=float).ravel()
    except (TypeError, ValueError) as exc:
        raise InputError(f"{name} must be numbers") from exc
    bad = ~np.isfinite(a)
    if bad.any():
        raise InputError(f"{name}: {int(bad.sum())} sample(s) are NaN or inf (first at index "
                         f"{int(np.flatnonzero(bad)[0])}); remove or re-record them")
    return a


def _quadrants_of(lo: float, hi: float) -> list[str]:
    """The quadrants (as '0-90°' ...) an open angular gap (lo, hi) overlaps, hi may exceed 360."""
    out = []
    for q in QUADRANTS_DEG:
        for shift in (0.0, 360.0):
            a, b = q + shift, q + shift + 90.0
            if lo < b and hi > a and f"{q:g}-{q + 90:g}°" not in out:
                out.append(f"{q:g}-{q + 90:g}°")
    return out


def _check_coverage(where: str, angle_deg: np.ndarray) -> None:
    s = np.sort(angle_deg)
    gaps = np.diff(np.concatenate([s, [s[0] + 360.0]]))
    wide = np.flatnonzero(gaps > MAX_GAP_DEG)
    if wide.size:
        spans = [(float(s[i]), float(s[i] + gaps[i])) for i in wide]
        quads = sorted({q for lo, hi in spans for q in _quadrants_of(lo, hi)}, key=lambda t: float(t.split("-")[0]))
        text = ", ".join(f"{lo:.1f}° to {hi % 360:.1f}°" for lo, hi in spans[:4])
        raise InputError(
            f"{where}: the samples do not cover the full circle: no samples from {text} (quadrant(s) "
            f"{', '.join(quads)} incomplete; gaps up to {MAX_GAP_DEG:g}° allowed): record the whole 360°")


def _check_sense(where: str, direction: str, angle_deg: np.ndarray) -> None:
    travel = float(np.sum(np.rad2deg(np.angle(np.exp(1j * np.deg2rad(np.diff(angle_deg)))))))
    if direction == "ccw" and travel < 0 or direction == "cw" and travel > 0:
        ran = "clockwise" if travel < 0 else "counter-clockwise"
        raise InputError(f"{where}: the angles run {ran} ({travel:+.0f}° in sampling order); the direction is "
                         "wrong, or the samples are not in the order the machine ran them")


def pass_from_positions(first_mm, second_mm, *, radius_mm: float, centre_mm=(0.0, 0.0),
                        direction: str) -> CirclePass:
    """One pass from the two axes' positions (mm) sampled along the circle, in the order
    the machine ran them, about the nominal ``centre_mm`` and ``radius_mm``."""
    r = require_positive("radius_mm", radius_mm)
    cx, cy = (require_finite("centre_mm", c) for c in centre_mm)
    a = _array("first_mm", first_mm)
    b = _array("second_mm", second_mm)
    if a.shape != b.shape:
        raise InputError(f"first_mm ({a.size} samples) and second_mm ({b.size}) must be of equal length")
    dx, dy = a - cx, b - cy
    ang = np.rad2deg(np.arctan2(dy, dx)) % 360.0
    ang[ang >= 360.0] = 0.0  # -tiny % 360 rounds to 360.0
    radial = (np.hypot(dx, dy) - r) * 1e3
    return CirclePass(direction=direction, angle_deg=ang, radial_um=radial)


def test_from_positions(positions: Mapping[str, tuple[Sequence[float], Sequence[float]]], *, radius_mm: float,
                        feed_mm_min: float, plane: tuple[str, str], instrument: Instrument,
                        centre_mm=(0.0, 0.0), temperature_c: float | None = None,
                        utility_day: float | None = None, source: str = "") -> CircularTest:
    """A test from ``{direction: (first_mm, second_mm)}`` (see :func:`pass_from_positions`)."""
    if not isinstance(positions, Mapping) or not positions:
        raise InputError("positions must map a direction ('ccw', 'cw') to (first_mm, second_mm)")
    passes = []
    for direction, pair in positions.items():
        try:
            first, second = pair
        except (TypeError, ValueError) as exc:
            raise InputError(f"positions[{direction!r}] must be a pair (first_mm, second_mm)") from exc
        passes.append(pass_from_positions(first, second, radius_mm=radius_mm, centre_mm=centre_mm,
                                          direction=direction))
    return CircularTest(radius_mm=radius_mm, feed_mm_min=feed_mm_min, plane=plane, passes=tuple(passes),
                        instrument=instrument, temperature_c=temperature_c, utility_day=utility_day, source=source)


test_from_positions.__test__ = False  # not a pytest test, despite its name
