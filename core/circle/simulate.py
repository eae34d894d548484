"""Circular tests from the project's twin of a feed drive (:mod:`core.sim`), for tests,
the CLI's simulated machine and the demo: the circle is what two simulated axes trace,
with backlash, friction, unequal gains, noise and quantisation, not a formula.

The data arc starts at 45° (between quadrant points), after a lead-in of ``settle_s``
at feed, so the loops' start-up lag has decayed before the first sample and no
reversal falls on the seam of the recording.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from core.circle.test import DIRECTIONS, CircularTest, Instrument, pass_from_positions
from core.errors import InputError, require_finite, require_positive
from core.sim import AxisModel, Effects, Encoders, Friction, ServoDynamics, circle, simulate

START_ANGLE_DEG = 45.0


def _pair(name: str, value, kind) -> tuple:
    if value is None or isinstance(value, kind):
        return (value, value)
    try:
        a, b = value
    except (TypeError, ValueError) as exc:
        raise InputError(f"{name} must be one value for both axes or a pair (first, second)") from exc
    return (a, b)


def simulated_test(*, radius_mm: float, feed_mm_min: float, gain_per_s: float, backlash_um=(0.0, 0.0),
                   friction: Friction | Sequence[Friction | None] | None = None, gain_mismatch: float = 0.0,
                   servo_dynamics: ServoDynamics | Sequence[ServoDynamics | None] | None = None,
                   noise_um: float = 0.0, resolution_um: float = 0.0, directions: Sequence[str] = DIRECTIONS,
                   plane: tuple[str, str] = ("x", "y"), rate_hz: float | None = None, settle_s: float | None = None,
                   temperature_c: float | None = None, seed: int = 0) -> CircularTest:
    """A circular test run on two simulated axes.

    ``gain_per_s`` is the first axis' position gain K; the second's is
    K (1 + ``gain_mismatch``) (unequal gains draw a 45° ellipse). ``backlash_um``,
    ``friction`` and ``servo_dynamics`` are one value for both axes or a pair
    (first, second). ``noise_um`` (white, standard deviation) and ``resolution_um``
    (quantisation) act on each axis' linear scale reading. ``rate_hz``: samples per
    second (None: about ten per degree of arc, at least 200 Hz). ``settle_s``: the
    lead-in at feed before the data arc (None: 20/K of the slower axis, so the start-up
    lag has decayed to e^-20 of itself).
    """
    r = require_positive("radius_mm", radius_mm)
    f = require_positive("feed_mm_min", feed_mm_min)
    k = require_positive("gain_per_s", gain_per_s)
    m = require_finite("gain_mismatch", gain_mismatch)
    if not -0.5 < m < 1.0:
        raise InputError(f"gain_mismatch (={gain_mismatch}) must be within -0.5..1 (a relative difference of K)")
    noise = require_finite("noise_um", noise_um)
    res = require_finite("resolution_um", resolution_um)
    if noise < 0 or res < 0:
        raise InputError(f"noise_um (={noise_um}) and resolution_um (={resolution_um}) must be >= 0")
    dirs = tuple(directions)
    if not dirs or any(d not in DIRECTIONS for d in dirs) or len(set(dirs)) != len(dirs):
        raise InputError(f"directions (={directions!r}) must be distinct values of {DIRECTIONS}")
    backlash = _pair("backlash_um", backlash_um, (int, float))
    frictions = _pair("friction", friction, Friction)
    servos = _pair("servo_dynamics", servo_dynamics, ServoDynamics)
    omega = f / 60.0 / r
    rate = max(200.0, 10.0 * math.degrees(omega)) if rate_hz is None else require_positive("rate_hz", rate_hz)
    plane = tuple(a.strip().lower() for a in plane)
    settle = 20.0 / min(k, k * (1.0 + m)) if settle_s is None else require_positive("settle_s", settle_s)
    encoders = Encoders(table_noise_um=noise, table_resolution_um=res)
    axes = {}
    for i, name in enumerate(plane):
        axes[name] = AxisModel(name=name, position_gain_per_s=k * (1.0 + m) if i == 1 else k,
                               backlash_um=float(backlash[i]),
                               effects=Effects(friction=frictions[i], servo_dynamics=servos[i]), encoders=encoders)
    rng = np.random.default_rng(seed)
    passes = []
    for d in dirs:
        prog = circle(r, (0.0, 0.0), f, d, START_ANGLE_DEG, 360.0, axes=plane, settle_s=settle)
        tr = simulate(axes, prog, rate_hz=rate, rng=rng, temperature_c=20.0 if temperature_c is None
                      else temperature_c)
        first, second = tr.table_mm[plane[0]], tr.table_mm[plane[1]]
        passes.append(pass_from_positions(first[:-1], second[:-1], radius_mm=r, direction=d))
    what = [f"K {k:g}/s" + (f" (second axis {k * (1 + m):g}/s)" if m else ""),
            f"backlash {backlash[0]:g}/{backlash[1]:g} µm"]
    if any(frictions):
        what.append("friction")
    if any(servos):
        what.append("servo dynamics")
    return CircularTest(
        radius_mm=r, feed_mm_min=f, plane=plane, passes=tuple(passes),
        instrument=Instrument("encoders", res, 0.0, name="simulated linear scales (exact)"),
        temperature_c=temperature_c, source="simulated: " + ", ".join(what))
