"""What the paper's closed loop looks like on LinuxCNC, from recorded samples: the circle
program and its quadrant bumps (the transient backlash error Eq. 8 predicts), and the lost
motion of a round trip's reversal (what a compensation table removes).

Pure functions of arrays (and a G-code text): the recordings come from
:mod:`acquisition.linuxcnc.contour` and :mod:`acquisition.linuxcnc.driver`.
"""

from __future__ import annotations

import numpy as np

from acquisition.linuxcnc.contour import ContourRecording
from acquisition.types import RoundTripProgram
from core.errors import InputError
from core.tbe.formulas import circle_steady_lag_um

#: The half circle runs counter-clockwise from START_DEG through X's reversal (0°) and
#: Y's (90°) to START_DEG + 180°.
START_DEG = -45.0
QUADRANTS_DEG = (0.0, 90.0)
#: The data arc (start, sweep) for the gap diagnosis: from 20° after the start to the end.
#: The first 20° start from rest, with the Y axis reversing (it came out along the radius
#: moving -): the start-up transient the diagnosis sets apart.
DATA_ARC_DEG = (START_DEG + 20.0, 160.0)


def half_circle_gcode(radius_mm: float, feed_mm_min: float) -> str:
    """G3 about the origin (G54) from -45° to 135°. Before it, the axes stop at the centre
    and go out along the start's radius, so every recording of it begins the same way
    (:func:`from_the_radial_approach`), and dwell at the start (its own transient settles
    before the first quadrant point)."""
    if not (radius_mm > 0 and feed_mm_min > 0):
        raise InputError(f"radius_mm (={radius_mm}) and feed_mm_min (={feed_mm_min}) must be > 0")
    c = radius_mm / np.sqrt(2.0)
    return (f"G21 G90 G17 G61 G54\nG1 X0 Y0 F{feed_mm_min:g}\nG4 P0.3\nG1 X{c:.4f} Y{-c:.4f}\nG4 P0.5\n"
            f"G3 X{-c:.4f} Y{c:.4f} I{-c:.4f} J{c:.4f} F{feed_mm_min:g}\nG4 P0.3\nM2\n")


def from_the_radial_approach(rec: ContourRecording, off_centre_mm: float = 0.5) -> ContourRecording:
    """The recording of :func:`half_circle_gcode` from the radial approach on (its command
    ``off_centre_mm`` out of the centre): the same start whatever came before, its angle
    the circle's start, the axes moving as they will into the arc."""
    r = np.hypot(*rec.command_mm)
    at_centre = np.flatnonzero(r < 1e-6)
    if at_centre.size == 0:
        raise InputError("the recording does not pass the circle's centre (not a half_circle_gcode run)")
    out = at_centre[-1] + np.flatnonzero(r[at_centre[-1]:] > off_centre_mm)
    if out.size == 0:
        raise InputError("the recording does not leave the circle's centre")
    return rec.since(int(out[0]))


def quadrant_bumps_um(rec: ContourRecording, radius_mm: float, feed_mm_min: float,
                      gain_per_s: float) -> tuple[dict[float, float], float]:
    """The radial error's largest value within 40° after each quadrant point, and its median
    between them, both from the circle the loop traces without backlash (R cos φ, as Eq. 8
    is): ``({0.0: bump_um, 90.0: bump_um}, between_um)``."""
    (x, y), (xc, yc) = rec.table_mm, rec.command_mm
    on_arc = np.abs(np.hypot(xc, yc) - radius_mm) < 1e-3
    angle_deg = np.degrees(np.arctan2(yc, xc))
    radial_um = np.hypot(x, y) * 1e3 - (radius_mm * 1e3 - circle_steady_lag_um(radius_mm, feed_mm_min, gain_per_s))
    between = on_arc & (((angle_deg > -30) & (angle_deg < -5)) | ((angle_deg > 50) & (angle_deg < 85)))
    bumps = {}
    for q in QUADRANTS_DEG:
        after = on_arc & (angle_deg >= q) & (angle_deg < q + 40.0)
        if not after.any():
            raise InputError(f"the recording does not pass the quadrant point at {q:g}°")
        bumps[q] = float(radial_um[after].max())
    return bumps, float(np.median(radial_um[between])) if between.any() else float("nan")


def reversal_lost_motion_um(table_mm: np.ndarray, command_mm: np.ndarray, program: RoundTripProgram) -> float:
    """Table minus command at rest at the reversal (approached moving out) minus the same at
    rest back at the start (approached moving back): the lost motion of the reversal. Each
    rest is the last fifth of the samples whose command sits at that end (give the program
    a dwell long enough for the loop to settle)."""
    err = np.asarray(table_mm) - np.asarray(command_mm)
    at_end = np.flatnonzero(np.abs(command_mm - program.end_mm) < 1e-6)
    if at_end.size < 10:
        raise InputError("the trace does not rest at the round trip's reversal")
    back = np.flatnonzero(np.abs(command_mm - program.start_mm) < 1e-6)
    back = back[back > at_end[-1]]
    if back.size < 10:
        raise InputError("the trace does not rest back at the round trip's start")
    return abs(float(np.mean(err[at_end[-(at_end.size // 5):]])) - float(np.mean(err[back[-(back.size // 5):]]))) * 1e3
