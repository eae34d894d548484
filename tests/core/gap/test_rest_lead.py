"""Round trips start their models where the table rested in the backlash, as measured.

The independent plant starts half of its runs with the nut on the far flank (the table
came to its start point from the other side): the nut must cross the gap before the table
moves. A model with mass behind the nut meets the table at speed after that crossing,
which a start on the driving flank leaves out.
"""

import dataclasses

import numpy as np
import pytest

from core.dataset import AxisSpec
from core.gap.candidates import GUIDE_DAMPING_PER_S, compose, friction_chain_stage, sim_piece, smooth_u
from core.gap.data import RoundTrip, rest_lead_mm
from core.gap.play import play_inertia
from core.plant_independent.drive import DriveParams, constant_lut, simulate_axis
from core.plant_independent.program import round_trip_program

B_UM = 80.0


def _round_trip(side: int, rate_hz: float = 1000.0) -> RoundTrip:
    """A noise-free round trip of the independent plant's rigid chain, the nut starting on
    the flank that drives a + move (side +1) or on the other one (-1)."""
    prog = round_trip_program("x", 100.0, 300.0, 1000.0, 800.0, 1.0, 0.01)
    tr = simulate_axis(DriveParams(gain_per_s=20.0), prog.command_mm["x"], prog.duration_s, constant_lut(0.0),
                       constant_lut(B_UM * 1e-3), side)  # fmt: skip
    t = np.arange(int(prog.duration_s * rate_hz)) / rate_hz
    u, x = tr.at(t)
    u = u + float(np.median(x - u))  # as prepare_round_trip aligns the motor to the table
    return RoundTrip("rt.csv", "x", "train", t, u, x, 20.0, 1000.0, 800.0, 1, np.arange(t.size),
                     rest_lead_mm=rest_lead_mm(t, u, x))  # fmt: skip


@pytest.mark.parametrize("side", [1, -1])
def test_the_rest_place_is_read_off_the_encoders(side):
    rt = _round_trip(side)
    assert rt.rest_lead_mm * 1e3 == pytest.approx(side * B_UM / 2, abs=0.1)
    # the model's table starts there, clipped to the model's own gap
    assert rt.start_table_mm(B_UM / 2e3) == pytest.approx(rt.u_mm[0] - side * B_UM / 2e3, abs=1e-7)
    assert rt.start_table_mm(0.01) == pytest.approx(rt.u_mm[0] - side * 0.01)


def test_a_run_that_never_comes_back_has_no_measured_place():
    t = np.arange(4000) / 1000.0
    u = np.clip(t - 1.0, 0.0, 2.0) * 10.0  # 1 s at rest, then 20 mm one way
    assert rest_lead_mm(t, u, u - 0.04) is None
    rt = dataclasses.replace(_round_trip(-1), rest_lead_mm=None)
    assert rt.start_table_mm(0.04) == pytest.approx(rt.u_mm[0] - 0.04)  # the driving flank (side0 = +1)


def test_a_chain_model_crosses_the_measured_gap_before_its_table_moves():
    """From the far flank the chain form's table stays until the motor has crossed the gap
    and wound the chain up to the static friction; from the driving flank only the
    winding up. The form chooses the place per run on the run itself (the measured one or
    either flank), so a wrong measured place (here: the driving flank) does not stand."""
    rt = _round_trip(-1)
    fn, mu, ex = 40.0, 1000.0, 2000.0
    w2 = (2 * np.pi * fn) ** 2
    b_app = B_UM + 2e3 * mu / w2  # the apparent backlash holds the Coulomb stretch
    model = compose([friction_chain_stage()], b_app, {})
    theta = np.array([b_app, fn, 0.1, mu, ex, 0.3])
    wind_um = 1e3 * (mu + ex) / w2
    half_gap_mm = 0.5e-3 * b_app - mu / w2

    def travel_before_motion_um(run, x=None):
        x = model.predict(theta, run) if x is None else x
        k = int(np.argmax(np.abs(x - x[0]) > 1e-4))
        return (run.u_mm[k] - run.u_mm[0]) * 1e3

    assert travel_before_motion_um(rt) == pytest.approx(B_UM + wind_um, abs=3.0)
    wrong = dataclasses.replace(rt, rest_lead_mm=half_gap_mm)
    assert travel_before_motion_um(wrong) == pytest.approx(B_UM + wind_um, abs=3.0)
    # the measured place alone would have started it on the driving flank
    us, vs = smooth_u(wrong, {})
    hb = np.full(rt.u_mm.size, half_gap_mm)
    x = play_inertia(us, vs, rt.t_s, hb, w2, 2 * 0.1 * np.sqrt(w2), GUIDE_DAMPING_PER_S, mu, 40,
                     wrong.start_table_mm(half_gap_mm), mu + ex, 0.3)  # fmt: skip
    assert travel_before_motion_um(wrong, x) == pytest.approx(wind_um, abs=3.0)


def test_the_contour_form_of_the_chain_carries_the_round_trips_stick_band():
    axis = AxisSpec("x", 10.0, 10.0, 20.0, (0.0, 800.0))
    p = {"chain_frequency_hz": 40.0, "chain_damping_ratio": 0.1, "coulomb_per_mass_mm_s2": 1000.0,
         "static_excess_per_mass_mm_s2": 2000.0, "stick_band_mm_s": 0.7}  # fmt: skip
    pieces, _ = sim_piece("friction", p, {"form": "chain"}, axis, 100.0)
    fr = dict(pieces)["friction"]
    assert fr.stick_band_mm_s == pytest.approx(0.7)
    assert fr.static_n / fr.coulomb_n == pytest.approx(3.0)
