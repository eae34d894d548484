"""``mebm tbe circle|line|limit``: the TBE of a machining task and its backlash limit."""

from __future__ import annotations

import argparse

from api.cli.output import print_json, print_table
from core.tbe import backlash_limit_um, circle_steady_lag_um, tbe_circle_um, tbe_line_um


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("tbe", help="transient backlash error of a task (Eqs. 7-11) and its backlash limit")
    tsub = p.add_subparsers(dest="tbe_command", metavar="PROFILE")
    tsub.required = True

    def common(q: argparse.ArgumentParser) -> None:
        q.add_argument("--feed-mm-min", type=float, required=True, help="programmed feed (mm/min)")
        q.add_argument("--gain-per-s", type=float, required=True, help="open-loop position gain K = k_a k_p (1/s)")
        q.add_argument("--json", action="store_true", help="print JSON")

    c = tsub.add_parser("circle", help="TBE at the quadrant points of a circle (Eq. 8)")
    c.add_argument("--backlash-um", type=float, required=True)
    c.add_argument("--radius-mm", type=float, required=True)
    common(c)
    c.set_defaults(func=_circle)

    ln = tsub.add_parser("line", help="TBE at the start of a straight line (Eq. 7)")
    ln.add_argument("--backlash-um", type=float, required=True)
    ln.add_argument("--angle-deg", type=float, required=True, help="angle to the reversely engaged X axis")
    common(ln)
    ln.set_defaults(func=_line)

    lim = tsub.add_parser("limit", help="largest permissible backlash for a tolerance")
    lim.add_argument("--tolerance-um", type=float, required=True, help="permissible error of the workpiece (µm)")
    shape = lim.add_mutually_exclusive_group(required=True)
    shape.add_argument("--radius-mm", type=float, help="circle task")
    shape.add_argument("--angle-deg", type=float, help="line task")
    common(lim)
    lim.set_defaults(func=_limit)


def _circle(a: argparse.Namespace) -> int:
    tbe = float(tbe_circle_um(a.backlash_um, a.radius_mm, a.feed_mm_min, a.gain_per_s))
    lag = circle_steady_lag_um(a.radius_mm, a.feed_mm_min, a.gain_per_s)
    result = {
        "profile": "circle",
        "backlash_um": a.backlash_um,
        "radius_mm": a.radius_mm,
        "feed_mm_min": a.feed_mm_min,
        "gain_per_s": a.gain_per_s,
        "tbe_um": tbe,
        "steady_lag_um": lag,
        "radial_peak_from_programmed_um": tbe - lag,
    }
    if a.json:
        print_json(result)
    else:
        print(f"TBE (Eq. 8, relative to the backlash-free circle): {tbe:.2f} µm")
        print(f"radial peak relative to the programmed circle:   {tbe - lag:.2f} µm (steady lag {lag:.2f} µm)")
    return 0


def _line(a: argparse.Namespace) -> int:
    tbe = float(tbe_line_um(a.backlash_um, a.angle_deg, a.feed_mm_min, a.gain_per_s))
    result = {
        "profile": "line",
        "backlash_um": a.backlash_um,
        "angle_deg": a.angle_deg,
        "feed_mm_min": a.feed_mm_min,
        "gain_per_s": a.gain_per_s,
        "tbe_um": tbe,
    }
    if a.json:
        print_json(result)
    else:
        print(f"TBE (Eq. 7): {tbe:.2f} µm")
    return 0


def _limit(a: argparse.Namespace) -> int:
    limit = backlash_limit_um(
        a.tolerance_um,
        feed_mm_min=a.feed_mm_min,
        gain_per_s=a.gain_per_s,
        radius_mm=a.radius_mm,
        angle_deg=a.angle_deg,
    )
    result = {
        "profile": "circle" if a.radius_mm is not None else "line",
        "tolerance_um": a.tolerance_um,
        "feed_mm_min": a.feed_mm_min,
        "gain_per_s": a.gain_per_s,
        "backlash_limit_um": limit,
    }
    if a.radius_mm is not None:
        result["radius_mm"] = a.radius_mm
    else:
        result["angle_deg"] = a.angle_deg
    if a.json:
        print_json(result)
    else:
        print_table(["tolerance (µm)", "largest permissible backlash (µm)"], [[a.tolerance_um, round(limit, 1)]])
    return 0
