"""Noise-free single runs of the independent plant with hand-set parameters."""

import numpy as np

from core.plant_independent.case import AXES, record_program
from core.plant_independent.program import circle_program, round_trip_program

K_PER_S = 15.0
K_A_MM_PER_REV = 8.0
B_UM = 60.0


def nominal(**over) -> dict:
    out = {"screw_lead_mm": 16.0, "transmission_mm_per_rev": K_A_MM_PER_REV, "position_gain_per_s": K_PER_S,
           "backlash_um": B_UM, "table_noise_um": 0.0, "motor_noise_um": 0.0, "motor_zero_rev": 3.25}  # fmt: skip
    out.update(over)
    return out


def round_trip(nom: dict, effects: dict | None = None, *, start=100.0, end=400.0, feed=1500.0, acc=800.0,
               temp=20.0, skew=None, jerk_s=0.01, rate=1000.0):  # fmt: skip
    """(t_s, command_mm, nut-side travel u_mm, table_mm) of a noise-free round trip of axis x."""
    prog = round_trip_program("x", start, end, feed, acc, 1.0, jerk_s)
    cols = record_program(prog, ("x",), temp, rate, {"x": nom}, {"x": effects or {}}, skew, np.random.default_rng(0),
                   noise=False)  # fmt: skip
    t = cols["time_s"] - cols["time_s"][0]
    u = (cols["x_motor_rev"] - nom["motor_zero_rev"]) * nom["transmission_mm_per_rev"]
    return t, cols["x_command_mm"], u, cols["x_table_mm"]


def circle(noms: dict, effects: dict | None = None, *, radius=50.0, feed=3000.0, acc=800.0, lead_in=180.0,
           lead_out=30.0, start=-90.0, direction="ccw", temp=20.0):  # fmt: skip
    prog, t_data = circle_program(AXES, radius, (400.0, 400.0), feed, acc, direction, start, 360.0, lead_in,
                                  lead_out, 0.01)  # fmt: skip
    eff = effects or {a: {} for a in AXES}
    cols = record_program(prog, AXES, temp, 500.0, noms, eff, None, np.random.default_rng(0), noise=False)
    t = cols["time_s"] - cols["time_s"][0]
    return t, t_data, cols
