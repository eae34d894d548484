import numpy as np
import pytest

from core.circle import CirclePass, CircularTest, Instrument, pass_from_positions, test_from_positions
from core.errors import InputError
from tests.core.circle.helpers import EXACT, drawn_path, drawn_test


def _pass(direction="ccw", n=720, lo=0.0, hi=360.0):
    ang = np.linspace(lo, hi, n, endpoint=False) % 360.0
    if direction == "cw":
        ang = ang[::-1]
    return CirclePass(direction, ang, np.zeros(n))


def test_pass_from_positions_reads_angle_and_radial_deviation_about_the_nominal_centre():
    x, y = drawn_path(20.0, "ccw", centre_um=(5.0, 0.0))
    p = pass_from_positions(x + 1.0, y - 2.0, radius_mm=20.0, centre_mm=(1.0, -2.0), direction="ccw")
    # a circle 5 µm off centre reads R + 5 cos θ about the nominal centre (to first order)
    assert np.allclose(p.radial_um, 5.0 * np.cos(np.deg2rad(p.angle_deg)), atol=1e-3)
    assert p.angle_deg.min() >= 0 and p.angle_deg.max() < 360
    assert np.all(np.diff(p.unwrapped_deg) > 0)  # ccw, in run order


def test_passes_are_sorted_ccw_first_and_read_only():
    t = drawn_test(directions=("cw", "ccw"))
    assert t.directions == ("ccw", "cw")
    with pytest.raises(ValueError):
        t.passes[0].radial_um[0] = 1.0


@pytest.mark.parametrize("bad, match", [
    (lambda: _pass(n=50), "at least 72"),
    (lambda: CirclePass("ccw", np.r_[np.nan, np.linspace(1, 359, 99)], np.zeros(100)), "NaN or inf"),
    (lambda: CirclePass("ccw", np.linspace(0, 359, 100), np.r_[np.inf, np.zeros(99)]), "NaN or inf"),
    (lambda: _pass(hi=250.0), r"quadrant\(s\) 180-270°, 270-360°"),
    (lambda: _pass(lo=100.0, hi=460.0 - 30.0), r"0-90°"),
    (lambda: CirclePass("up", np.linspace(0, 359, 100), np.zeros(100)), "direction"),
    (lambda: CirclePass("ccw", np.linspace(0, 360, 100), np.zeros(100)), r"\[0, 360\)"),
    (lambda: CirclePass("ccw", np.linspace(0, 359, 100), np.zeros(99)), "equal length"),
    (lambda: CirclePass("cw", np.linspace(0, 359, 100), np.zeros(100)), "run counter-clockwise"),
])
def test_bad_passes_are_refused_naming_the_field(bad, match):
    with pytest.raises(InputError, match=match):
        bad()


@pytest.mark.parametrize("kw, match", [
    ({"radius_mm": 0.0}, "radius_mm"),
    ({"radius_mm": -5.0}, "radius_mm"),
    ({"feed_mm_min": float("nan")}, "feed_mm_min"),
    ({"plane": ("x", "x")}, "two different axes"),
    ({"plane": ("x",)}, "two axes"),
    ({"passes": ()}, "at least one direction"),
    ({"passes": (_pass(), _pass())}, "repeated"),
    ({"instrument": "ballbar"}, "Instrument"),
    ({"temperature_c": float("inf")}, "temperature_c"),
])
def test_bad_tests_are_refused_naming_the_field(kw, match):
    args = dict(radius_mm=50.0, feed_mm_min=1000.0, plane=("x", "y"), passes=(_pass(),), instrument=EXACT)
    args.update(kw)
    with pytest.raises(InputError, match=match):
        CircularTest(**args)


def test_radial_deviation_in_the_wrong_unit_is_refused():
    # radial deviation given in mm*1e3*1e3 (nm) on a 5 mm circle: 1 mm off is 20 % of the radius
    p = CirclePass("ccw", np.linspace(0, 359, 360), np.full(360, 1000.0))
    with pytest.raises(InputError, match="beyond 10 % of radius_mm"):
        CircularTest(radius_mm=5.0, feed_mm_min=100.0, plane=("x", "y"), passes=(p,), instrument=EXACT)


@pytest.mark.parametrize("kw, match", [
    ({"kind": "laser"}, "kind"),
    ({"resolution_um": -1.0}, "resolution_um"),
    ({"accuracy_um": float("nan")}, "accuracy_um"),
])
def test_bad_instruments_are_refused(kw, match):
    args = {"kind": "ballbar", "resolution_um": 0.1, **kw}
    with pytest.raises(InputError, match=match):
        Instrument(**args)


def test_test_from_positions_needs_pairs():
    with pytest.raises(InputError, match="pair"):
        test_from_positions({"ccw": np.zeros(10)}, radius_mm=5, feed_mm_min=100, plane=("x", "y"),
                            instrument=EXACT)
    with pytest.raises(InputError, match="equal length"):
        pass_from_positions(np.zeros(10), np.zeros(11), radius_mm=5, direction="ccw")
