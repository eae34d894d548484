"""Compensation tables of a twin round trip, read back as each controller reads them,
reproduce the twin's known b(x) and lead error."""

from __future__ import annotations

import numpy as np
import pytest

from api.service.compensation import MAX_POINTS, LoopOnScaleError, export
from core.criteria import analyze_round_trip
from tests.api.service.comp_twin import AXIS, TRAVEL_MM, read_beckhoff, read_linuxcnc, simulate_round_trip, truth_um

TOL_UM = 0.5


@pytest.fixture(scope="module")
def result():
    tr = simulate_round_trip()
    return analyze_round_trip(tr.time_s, tr.motor_rev["y"], tr.table_mm["y"], AXIS.to_axis_spec(TRAVEL_MM))


def _assert_reproduces(nominal_mm, fwd_um, rev_um):
    t_fwd, t_rev = truth_um(nominal_mm, reference_mm=0.0)
    assert np.max(np.abs(fwd_um - t_fwd)) < TOL_UM
    assert np.max(np.abs(rev_um - t_rev)) < TOL_UM
    assert np.max(np.abs((rev_um - fwd_um) - (t_rev - t_fwd))) < TOL_UM  # b(x), Eq. 5


@pytest.mark.parametrize("comp_type", [0, 1])
def test_linuxcnc_table_reproduces_the_twin(result, comp_type):
    ex = export(result, "linuxcnc", comp_type=comp_type, joint=1, reference_mm=0.0)
    nom, fwd, rev = read_linuxcnc(ex.text, comp_type)
    assert nom.size == 61 and nom[0] == 0.0 and nom[-1] == 300.0 and np.all(np.diff(nom) == pytest.approx(5.0))
    _assert_reproduces(nom, fwd, rev)
    # the truth has real content: the table is not trivially close to it
    t_fwd, t_rev = truth_um(nom)
    assert np.ptp(t_rev - t_fwd) > 50.0 and np.ptp(t_fwd) > 10.0
    notes = ex.text[ex.text.index("#"):]
    assert "BACKLASH is ignored" in notes and f"COMP_FILE_TYPE = {comp_type}" in notes and "[JOINT_1]" in notes
    assert ex.media_type == "text/plain" and ex.filename.endswith(f"_type{comp_type}.comp")


def test_linuxcnc_types_describe_the_same_table(result):
    _, f0, r0 = read_linuxcnc(export(result, "linuxcnc", comp_type=0).text, 0)
    _, f1, r1 = read_linuxcnc(export(result, "linuxcnc", comp_type=1).text, 1)
    assert np.max(np.abs(f0 - f1)) < 1e-3 and np.max(np.abs(r0 - r1)) < 1e-3


def test_beckhoff_list_reproduces_the_twin(result):
    ex = export(result, "beckhoff", reference_mm=0.0)
    setpoint_mm, pos_um, neg_um = read_beckhoff(ex.text)
    assert setpoint_mm[0] == 0.0 and setpoint_mm[-1] == pytest.approx(300.0)
    _assert_reproduces(setpoint_mm, pos_um, neg_um)
    assert "getriebe[i].lose (P-AXIS-00103" in ex.text and "kw.ssfk.interval 50000" in ex.text


def test_csv_reproduces_the_twin(result):
    text = export(result, "csv", reference_mm=0.0).text
    lines = [ln for ln in text.splitlines() if not ln.startswith("#")]
    assert lines[0] == "position_mm,forward_um,reverse_um,backlash_um"
    x, f, r, b = np.loadtxt(lines[1:], delimiter=",", unpack=True)
    _assert_reproduces(x, f, r)
    assert np.allclose(b, r - f, atol=2e-3)


@pytest.mark.parametrize("fmt", ["linuxcnc", "beckhoff", "csv"])
def test_every_export_states_the_mean_backlash_and_the_loop(result, fmt):
    text = export(result, fmt).text
    text.encode("ascii")  # controllers' list readers are ASCII: no µ, ±, or ° in the notes either
    assert f"mean backlash b = {result.backlash_mean_um:.1f} " in text
    assert "position loop closed on: the motor encoder" in text


@pytest.mark.parametrize(("fmt", "step_mm"), [("linuxcnc", 0.5), ("beckhoff", 0.1)])
def test_point_limits_coarsen_the_step_and_still_reproduce(result, fmt, step_mm):
    ex = export(result, fmt, step_mm=step_mm, reference_mm=0.0)
    if fmt == "linuxcnc":
        nom, fwd, rev = read_linuxcnc(ex.text, 1)
    else:
        nom, fwd, rev = read_beckhoff(ex.text)
    assert nom.size == MAX_POINTS[fmt]  # 256 triplets per joint; kw_nr_max < max_points (1500)
    assert ex.table.coarsened and ex.table.step_mm > step_mm and "coarsened from" in ex.text
    assert nom[0] == 0.0 and TRAVEL_MM[1] - 2 * ex.table.step_mm < nom[-1] <= TRAVEL_MM[1]
    _assert_reproduces(nom, fwd, rev)


def test_a_loop_closed_on_the_scale_gets_no_table(result):
    with pytest.raises(LoopOnScaleError, match="linear scale"):
        export(result, "linuxcnc", loop_encoder="table")


def test_bad_format_and_type_are_named(result):
    with pytest.raises(ValueError, match="format"):
        export(result, "fanuc")
    with pytest.raises(ValueError, match="comp_type"):
        export(result, "linuxcnc", comp_type=2)
