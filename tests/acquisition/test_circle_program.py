"""The circular test's program and data arc (acquisition.circle) without a controller: the
G-code of each plane and direction, the 360° cut from a recording of the program (its
centre read from the command, whatever the work offset), and the typed refusals of a
recording that does not close, of swapped sampler axes and of URLs that cannot run a
circle."""

from __future__ import annotations

import math

import numpy as np
import pytest

from acquisition.circle import CircleProgram, circle_gcode, data_arc, measure_circle, sim_options
from acquisition.errors import IncompleteCircleError, ProtocolError
from core.circle import pass_from_positions
from core.errors import InputError

PROGRAM = CircleProgram(20.0, 2000.0)


@pytest.mark.parametrize("plane, direction, gcode, arc, words", [
    ("xy", "ccw", "G17", "G3", ("I", "J")),
    ("xy", "cw", "G17", "G2", ("I", "J")),
    ("yx", "ccw", "G17", "G2", ("J", "I")),  # ccw from +Y towards +X is clockwise in X-Y
    ("xz", "ccw", "G18", "G2", ("I", "K")),  # G18's G3 turns from Z towards X
    ("zx", "ccw", "G18", "G3", ("K", "I")),
    ("yz", "cw", "G19", "G2", ("J", "K")),
])
def test_the_program_turns_the_asked_direction_in_each_plane(plane, direction, gcode, arc, words):
    text = circle_gcode(CircleProgram(20.0, 2000.0, plane=plane), direction)
    block = next(line for line in text.splitlines() if line.startswith(("G2 ", "G3 ")))
    assert gcode in text and block.startswith(arc) and " P2 " in block
    assert all(f" {w}" in block for w in words)


@pytest.mark.parametrize("radius_mm, feed_mm_min, lead_in_deg, turns", [
    (50.0, 2000.0, 90.0, 2),   # 38° in a second: the next point midway between quadrant points
    (20.0, 2000.0, 180.0, 2),  # 95° in a second
    (10.0, 3000.0, 360.0, 3),  # 286° in a second: the arc runs two full turns and the rest
    (200.0, 200.0, 90.0, 2),   # 1° in a second: at least 20°
])
def test_the_lead_in_lasts_a_second_and_ends_midway_between_quadrant_points(radius_mm, feed_mm_min, lead_in_deg,
                                                                            turns):
    p = CircleProgram(radius_mm, feed_mm_min)
    assert p.lead_in_deg == lead_in_deg and p.turns == turns
    assert math.radians(p.lead_in_deg) * radius_mm / (feed_mm_min / 60.0) >= min(1.0, p.lead_in_deg)
    block = next(line for line in circle_gcode(p, "cw").splitlines() if line.startswith("G2 "))
    end_deg = p.start_deg - (p.sweep_deg - 360.0 * (turns - 1))
    assert f" P{turns} " in block and f"X{radius_mm * math.cos(math.radians(end_deg)):.6f}" in block


def recording(program: CircleProgram, direction: str, centre=(0.0, 0.0), *, stop_deg: float | None = None,
              lag_samples: int = 30):
    """A recording of ``circle_gcode`` at 1 kHz: the command (from a rest elsewhere, to the
    centre, out to the start, the arc, a rest) and the table following it ``lag_samples``
    behind."""
    r, f = program.radius_mm, program.feed_mm_min / 60.0
    a0 = math.radians(program.start_deg)
    pts = [np.tile([[centre[0] + 7.0, centre[1] - 3.0]], (80, 1))]  # where the axes were
    pts.append(np.linspace(pts[0][-1], centre, 200))
    pts.append(np.tile([centre], (300, 1)))
    start = np.array(centre) + r * np.array([math.cos(a0), math.sin(a0)])
    pts.append(np.linspace(centre, start, int(r / f * 1000)))
    pts.append(np.tile([start], (500, 1)))
    sweep = program.sweep_deg if stop_deg is None else stop_deg
    n = int(math.radians(sweep) * r / f * 1000)
    s = 1.0 if direction == "ccw" else -1.0
    ang = a0 + s * np.linspace(0.0, math.radians(sweep), n)[1:]
    pts.append(np.column_stack([centre[0] + r * np.cos(ang), centre[1] + r * np.sin(ang)]))
    pts.append(np.tile(pts[-1][-1:], (300, 1)))
    cmd = np.concatenate(pts)
    table = np.concatenate([np.tile(cmd[:1], (lag_samples, 1)), cmd[:-lag_samples]])
    return (cmd[:, 0], cmd[:, 1]), (table[:, 0], table[:, 1])


@pytest.mark.parametrize("direction", ["ccw", "cw"])
def test_the_data_arc_is_the_360_degrees_after_the_lead_in_about_the_commanded_centre(direction):
    centre = (112.5, -40.25)  # a work offset mebm is not told
    cmd, table = recording(PROGRAM, direction, centre)
    arc = data_arc(cmd, table, PROGRAM, direction)
    assert arc.centre_mm == pytest.approx(centre, abs=1e-9)
    assert arc.swept_deg == pytest.approx(PROGRAM.sweep_deg, abs=0.1)
    p = pass_from_positions(arc.first_mm, arc.second_mm, radius_mm=20.0, centre_mm=arc.centre_mm, direction=direction)
    u = p.unwrapped_deg
    assert 359.0 < abs(u[-1] - u[0]) < 360.0
    # the table lags the command by 30 samples (1.4°): its first angle is the lead-in's end less that lag
    lag_deg = math.degrees(30e-3 * PROGRAM.feed_mm_min / 60.0 / PROGRAM.radius_mm)
    sign = 1.0 if direction == "ccw" else -1.0
    first = (PROGRAM.start_deg + sign * (PROGRAM.lead_in_deg - lag_deg)) % 360.0
    assert p.angle_deg[0] == pytest.approx(first, abs=0.1)
    assert np.abs(p.radial_um).max() < 1e-6  # the table on the circle


def test_a_recording_stopped_before_the_arc_closes_is_an_incomplete_circle():
    cmd, table = recording(PROGRAM, "ccw", stop_deg=300.0)
    with pytest.raises(IncompleteCircleError,
                       match=rf"does not close: the command ran 300\.0° of the {PROGRAM.sweep_deg:g}°") as exc:
        data_arc(cmd, table, PROGRAM, "ccw")
    assert exc.value.reason_code == "incomplete_circle"


def test_a_recording_that_never_reaches_the_start_is_an_incomplete_circle():
    cmd, table = recording(PROGRAM, "ccw")
    with pytest.raises(IncompleteCircleError, match="cut short"):
        data_arc(tuple(a[:500] for a in cmd), tuple(a[:500] for a in table), PROGRAM, "ccw")


def test_swapped_sampler_axes_are_named():
    cmd, table = recording(PROGRAM, "ccw")
    with pytest.raises(ProtocolError, match=r"pins 0\.\.2"):
        data_arc(cmd[::-1], table[::-1], PROGRAM, "ccw")


def test_the_wrong_direction_is_named():
    cmd, table = recording(PROGRAM, "cw")
    with pytest.raises(ProtocolError, match="turned the other way than ccw"):
        data_arc(cmd, table, PROGRAM, "ccw")


@pytest.mark.parametrize("url, message", [
    ("sim://127.0.0.1:5020", "one axis"),
    ("sim:?backlash_um=1,2,3", "one or two numbers"),
    ("sim:?friction=3", "unknown option"),
    ("sim:?gain_per_s=0", "gain_per_s"),
])
def test_a_bad_simulated_machine_url_is_refused_naming_the_key(url, message):
    with pytest.raises(InputError, match=message):
        sim_options(url)


@pytest.mark.parametrize("url, message", [
    ("modbus://10.0.4.21:502", "mebm circle import"),
    ("canopen://socketcan/can0?node=7", "cannot record a two-axis circle"),
    ("linuxcnc://127.0.0.1:5007?joint=0", r"unknown option\(s\) \['joint'\]"),
    ("linuxcnc://127.0.0.1:5007?sampler=2", "--resolution-um"),
    ("ftp://x", "linuxcnc://HOST:PORT"),
])
def test_a_url_that_cannot_run_a_circle_is_refused_saying_what_can(url, message):
    with pytest.raises(InputError, match=message):
        measure_circle(url, PROGRAM, resolution_um=None if "sampler" in url else 1.0)


def test_the_simulated_machine_measures_both_directions_with_its_parameters():
    test = measure_circle("sim:?backlash_um=80,0&gain_per_s=25", CircleProgram(30.0, 1500.0, plane="yz"),
                          temperature_c=21.5)
    assert test.directions == ("ccw", "cw") and test.plane == ("y", "z") and test.temperature_c == 21.5
    assert test.source.startswith("simulated: sim:?backlash_um=80,0")
    from core.circle import analyze

    heights = {s.axis: s.height_um for s in analyze(test).spikes}
    assert heights["y"] > 10.0 > heights["z"]  # the backlash of the first axis only
