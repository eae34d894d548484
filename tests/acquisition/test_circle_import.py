"""Circle-import profiles (acquisition.circle_import) on files written here: a trace tool's
positions (the circles found about the centre, each one's start-up left out), a ballbar's
angle counted in radians the other way round, ragged direction groups, and the refusals
that name the line, the column or the profile's field and what to give."""

from __future__ import annotations

import math

import numpy as np
import pytest

from acquisition.circle_import import CircleImportError, parse_profile, read_circle
from core.circle import analyze

R_MM, F_MM_MIN, CENTRE = 25.0, 1500.0, (3.0, -4.0)
INSTRUMENT = {"kind": "trace", "resolution_um": 0.5}


def positions_profile(**test) -> dict:
    return {"format": "mebm-circle-profile/1", "layout": "positions", "csv": {"delimiter": ";"},
            "columns": {"time": {"name": "t", "unit": "s"}, "first": {"name": "X", "unit": "mm"},
                        "second": {"name": "Y", "unit": "um"}},
            "test": {"radius_mm": R_MM, "feed_mm_min": F_MM_MIN, "centre_mm": list(CENTRE), **test},
            "instrument": INSTRUMENT}


def circle_rows(direction: str, sweep_deg: float, t0: float) -> list[tuple[float, float, float]]:
    """From the centre out to -45°, a dwell, ``sweep_deg`` of arc at the feed with a 6 µm bump
    10° after the 90° quadrant point (in the direction of travel), a dwell: 1 kHz."""
    s = 1.0 if direction == "ccw" else -1.0
    a0 = math.radians(-45.0)
    out = [np.zeros(300)]
    out.append(np.linspace(0.0, R_MM, 400))
    out.append(np.full(300, R_MM))
    w = F_MM_MIN / 60.0 / R_MM
    t = np.arange(0.0, math.radians(sweep_deg) / w, 1e-3)
    ang = a0 + s * w * t
    bump_at = math.radians(90.0 + s * 10.0)
    dev = 6e-3 * np.exp(-0.5 * (np.angle(np.exp(1j * (ang - bump_at))) / math.radians(2.0)) ** 2)
    radius = np.concatenate([*out, R_MM + dev, np.full(300, R_MM)])
    angle = np.concatenate([np.full(1000, a0), ang, np.full(300, ang[-1])])
    x, y = CENTRE[0] + radius * np.cos(angle), CENTRE[1] + radius * np.sin(angle)
    time = t0 + np.arange(x.size) * 1e-3
    return list(zip(time, x, y))


def write_positions(path, sweeps=(("ccw", 480.0), ("cw", 480.0))):
    rows, t0 = [], 0.0
    for d, sweep in sweeps:
        rows += circle_rows(d, sweep, t0)
        t0 = rows[-1][0] + 1.0
    path.write_text("t;X;Y\n" + "".join(f"{t:.4f};{x:.6f};{y * 1e3:.3f}\n" for t, x, y in rows))
    return path


def test_a_trace_s_two_circles_are_found_and_each_start_up_left_out(tmp_path):
    test = read_circle(write_positions(tmp_path / "trace.csv"), parse_profile(positions_profile()))
    assert test.directions == ("ccw", "cw") and test.instrument.kind == "trace"
    for p in test.passes:
        u = p.unwrapped_deg
        assert 359.5 < abs(u[-1] - u[0]) < 360.0
        s = 1.0 if p.direction == "ccw" else -1.0
        # the first second of arc (57°) extended to midway between quadrant points: a 90° lead-in
        assert p.angle_deg[0] == pytest.approx((-45.0 + s * 90.0) % 360.0, abs=0.1)
        peak = int(np.argmax(p.radial_um))
        assert p.radial_um[peak] == pytest.approx(6.0, abs=0.01)
        assert p.angle_deg[peak] == pytest.approx(90.0 + s * 10.0, abs=0.1)
    spikes = {(s.direction, s.quadrant_deg): s.height_um for s in analyze(test).spikes}
    assert spikes[("ccw", 90.0)] == pytest.approx(6.0, abs=0.2) and spikes[("ccw", 0.0)] < 0.2


def test_a_trace_whose_circle_is_short_is_refused_naming_the_lead_in(tmp_path):
    path = write_positions(tmp_path / "short.csv", (("ccw", 480.0), ("cw", 300.0)))
    with pytest.raises(CircleImportError, match=r"longest cw arc .* runs 299\.9°, and the test needs 450°: a lead-in "
                                                r"of 90° \(the start-up's first 57°, test\.lead_in_deg"):
        read_circle(path, parse_profile(positions_profile()))
    # without a lead-in it still does not close: 300° is not a circle
    with pytest.raises(CircleImportError, match="the test needs 360°"):
        read_circle(path, parse_profile(positions_profile(lead_in_deg=0)))


def test_a_trace_about_another_centre_is_refused_naming_the_centre_it_circles(tmp_path):
    path = write_positions(tmp_path / "trace.csv")
    with pytest.raises(CircleImportError, match="--centre-mm") as exc:
        read_circle(path, parse_profile(positions_profile(centre_mm=[0.0, 0.0])))
    given = [float(v) for v in str(exc.value).split("--centre-mm ")[1].split()[:2]]
    assert given == pytest.approx(CENTRE, abs=2e-4)  # the rests at the start and end weigh in a little
    assert read_circle(path, parse_profile(positions_profile(centre_mm=given))).directions == ("ccw", "cw")


def radial_profile(columns: dict, **csv) -> dict:
    return {"format": "mebm-circle-profile/1", "layout": "radial", "csv": csv, "columns": columns,
            "test": {"radius_mm": R_MM, "feed_mm_min": F_MM_MIN}, "instrument": {"kind": "ballbar",
                                                                                "resolution_um": 0.1}}


def ballbar_rows(direction: str, n: int = 720):
    s = 1.0 if direction == "ccw" else -1.0
    ang = (s * np.arange(n) * 360.0 / n) % 360.0
    return ang, 2.0 * np.cos(np.deg2rad(2 * ang))  # a 45° ellipse of ±2 µm


def test_angles_in_radians_counted_clockwise_and_ragged_groups_import(tmp_path):
    ccw_a, ccw_r = ballbar_rows("ccw", 720)
    cw_a, cw_r = ballbar_rows("cw", 700)
    lines = ["a1\td1\ta2\td2"]
    for i in range(720):
        right = [f"{-np.deg2rad(cw_a[i]):.8f}", f"{cw_r[i]:.5f}"] if i < 700 else ["", ""]
        lines.append("\t".join([f"{-np.deg2rad(ccw_a[i]):.8f}", f"{ccw_r[i]:.5f}", *right]))
    path = tmp_path / "bb.txt"
    path.write_text("\n".join(lines) + "\n")
    clockwise = {"unit": "rad", "scale": -1.0}
    profile = parse_profile(radial_profile({"ccw": {"angle": {"name": "a1", **clockwise}, "deviation": {
        "name": "d1", "unit": "um"}}, "cw": {"angle": {"name": "a2", **clockwise}, "deviation": {"name": "d2",
                                                                                             "unit": "um"}}},
        delimiter="\t"))
    test = read_circle(path, profile)
    assert test.pass_of("ccw").angle_deg.size == 720 and test.pass_of("cw").angle_deg.size == 700
    np.testing.assert_allclose(test.pass_of("ccw").angle_deg, ccw_a, atol=1e-5)
    np.testing.assert_allclose(test.pass_of("cw").radial_um, cw_r, atol=1e-5)


def test_a_blank_inside_a_direction_s_columns_is_refused_with_its_line(tmp_path):
    a, r = ballbar_rows("ccw")
    b, q = ballbar_rows("cw")
    rows = [f"{a[i]:.4f},{r[i]:.4f},{b[i]:.4f},{q[i]:.4f}" for i in range(a.size)]
    rows[99] = f"{a[99]:.4f},,{b[99]:.4f},{q[99]:.4f}"
    path = tmp_path / "bb.csv"
    path.write_text("A,D,B,E\n" + "\n".join(rows) + "\n")
    profile = parse_profile(radial_profile({"ccw": {"angle": {"name": "A", "unit": "deg"}, "deviation": {
        "name": "D", "unit": "um"}}, "cw": {"angle": {"name": "B", "unit": "deg"}, "deviation": {"name": "E",
                                                                                              "unit": "um"}}}))
    with pytest.raises(CircleImportError, match=r"line 101, column 'D': '' is not a finite number"):
        read_circle(path, profile)


def test_a_direction_the_profile_does_not_name_is_refused_with_the_mapping(tmp_path):
    a, r = ballbar_rows("ccw")
    lines = ["ang;dev;dir"] + [f"{x:.4f};{y:.4f};{'links' if i == 5 else 'GUZ'}".replace(".", ",")
                               for i, (x, y) in enumerate(zip(a, r))]
    path = tmp_path / "bb.csv"
    path.write_text("\n".join(lines) + "\n")
    profile = parse_profile(radial_profile({"angle": {"name": "ang", "unit": "deg"},
                                            "deviation": {"name": "dev", "unit": "um"},
                                            "direction": {"name": "dir", "ccw": "GUZ", "cw": "UZ"}},
                                           delimiter=";", decimal=","))
    with pytest.raises(CircleImportError, match=r"line 7, column 'dir': 'links' is not a direction the profile "
                                                r"names \(columns\.direction\.ccw = 'GUZ', \.cw = 'UZ'\)"):
        read_circle(path, profile)


@pytest.mark.parametrize("change, message", [
    ({"layout": "polar"}, "layout"),
    ({"format": "mebm-trace-profile/1"}, "format"),
    ({"columns": {"time": {"name": "t", "unit": "h"}, "first": {"name": "X", "unit": "mm"},
                  "second": {"name": "Y", "unit": "mm"}}}, r"columns\.time\.unit"),
    ({"columns": {"time": {"name": "t", "unit": "s"}, "first": {"name": "X", "unit": "mm"},
                  "second": {"name": "X", "unit": "mm"}}}, "more than one value"),
    ({"csv": {"decimal": ";", "delimiter": ";"}}, r"csv\.decimal"),
])
def test_a_bad_profile_is_refused_naming_the_field(change, message):
    with pytest.raises(CircleImportError, match=message):
        parse_profile({**positions_profile(), **change})


def test_a_profile_without_an_instrument_is_refused_naming_its_fields(tmp_path):
    doc = positions_profile()
    del doc["instrument"]
    with pytest.raises(CircleImportError, match=r"\[instrument\].*resolution_um"):
        read_circle(write_positions(tmp_path / "t.csv"), parse_profile(doc))


def test_angles_counted_the_other_way_are_refused_naming_the_scale_that_fixes_them(tmp_path):
    a, r = ballbar_rows("ccw")
    b, q = ballbar_rows("cw")
    lines = ["ang,dev,dir"] + [f"{(-x) % 360:.4f},{y:.4f},CCW" for x, y in zip(a, r)]
    lines += [f"{(-x) % 360:.4f},{y:.4f},CW" for x, y in zip(b, q)]
    path = tmp_path / "bb.csv"
    path.write_text("\n".join(lines) + "\n")
    columns = {"angle": {"name": "ang", "unit": "deg"}, "deviation": {"name": "dev", "unit": "um"},
               "direction": {"name": "dir", "ccw": "CCW", "cw": "CW"}}
    with pytest.raises(CircleImportError, match=r"the ccw direction \(lines 2\.\.721\).*run clockwise.*"
                                                r"columns\.angle\.scale = -1"):
        read_circle(path, parse_profile(radial_profile(columns)))
    columns["angle"]["scale"] = -1.0
    assert read_circle(path, parse_profile(radial_profile(columns))).directions == ("ccw", "cw")
