import numpy as np
import pytest

from core.errors import InputError
from core.sim import circle, line, round_trip


def test_round_trip_goes_out_and_back_within_feed_and_acceleration():
    p = round_trip(0.0, 100.0, 1200.0, acceleration_mm_s2=400.0, dwell_s=0.5)
    t = np.linspace(0, p.duration_s, 20001)
    c = p.command_mm(t)["y"]
    v = np.gradient(c, t)
    assert c[0] == 0.0 and c[-1] == pytest.approx(0.0, abs=1e-12)
    assert c.max() == pytest.approx(100.0)
    assert np.abs(v).max() <= 20.0 * (1 + 1e-6)
    assert np.abs(np.diff(v) / np.diff(t)).max() <= 400.0 * 1.01
    assert p.initial_sides == ("positive",)
    assert round_trip(100.0, 0.0, 1200.0).initial_sides == ("negative",)


def test_round_trip_without_ramp_jumps_to_feed():
    p = round_trip(0.0, 10.0, 600.0, acceleration_mm_s2=None, dwell_s=1.0)
    c = p.command_mm(np.array([1.0, 1.1]))["y"]
    assert c[1] - c[0] == pytest.approx(1.0)


def test_circle_records_the_data_arc_on_the_circle_after_a_lead_in():
    p = circle(50.0, (10.0, -5.0), 1500.0, "cw", start_angle_deg=90.0, sweep_deg=180.0)
    assert p.record_from_s > 0.99  # at least settle_s of lead-in
    t = np.linspace(p.record_from_s, p.record_to_s, 5)
    xy = p.positions(t)
    ang = np.degrees(np.arctan2(xy[1] + 5.0, xy[0] - 10.0))
    assert np.hypot(xy[0] - 10.0, xy[1] + 5.0) == pytest.approx(np.full(5, 50.0))
    assert ang[0] == pytest.approx(90.0) and ang[2] == pytest.approx(0.0, abs=1e-6)
    assert p.record_to_s - p.record_from_s == pytest.approx(np.pi * 50.0 / 25.0)


def test_circle_initial_sides_follow_the_first_motion():
    # ccw from -90 deg: x moves +, y is at its minimum and will move +.
    assert circle(10.0, feed_mm_min=100.0, start_angle_deg=-90.0, lead_in_deg=0).initial_sides == (
        "positive",
        "positive",
    )
    # cw from 0 deg: x at its maximum moves -, y moves -.
    assert circle(10.0, feed_mm_min=100.0, direction="cw", start_angle_deg=0.0, lead_in_deg=0).initial_sides == (
        "negative",
        "negative",
    )


def test_line_starts_x_reversely_and_y_directly_engaged():
    p = line(30.0, 20.0, 600.0)
    assert p.initial_sides == ("negative", "positive")
    xy = p.positions(np.array([0.0, 1.0]))
    assert xy[:, 1] == pytest.approx([10.0 * np.cos(np.pi / 6), 10.0 * np.sin(np.pi / 6)])


@pytest.mark.parametrize(
    "make",
    [
        lambda: round_trip(0.0, 0.0, 100.0),
        lambda: round_trip(0.0, 1.0, -5.0),
        lambda: circle(0.0),
        lambda: circle(10.0, direction="left"),
        lambda: line(0.0, -1.0, 100.0),
    ],
)
def test_invalid_programs_raise_input_error(make):
    with pytest.raises(InputError):
        make()
