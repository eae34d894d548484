"""Contours driven by their recorded command and scored on the data arc only.

A circle recorded as ballbar programs record it (a feed-in arc before the data arc, or
at rest on the start angle) is explained by the nominal model to the noise floor; a
dataset without command columns still works and says it rebuilt the program; two
diagnoses in one process do not share simulations.
"""

from dataclasses import replace

import numpy as np
import pytest

from core.dataset import Dataset, MachineSpec, Run
from core.gap import diagnose
from core.gap.data import prepare_contour
from core.sim import AxisModel, Encoders, circle, simulate

ENC = Encoders(table_noise_um=0.3, motor_noise_um=0.3)


def _axes(backlash_um=(40.0, 70.0), gain=(12.0, 25.0)):
    return {a: AxisModel(name=a, transmission_mm_per_rev=8.0, screw_lead_mm=16.0, position_gain_per_s=k,
                         backlash_um=b, encoders=ENC) for a, b, k in zip("xy", backlash_um, gain)}


def _circles(axes, lead_in_deg, rng, *, cmd=True, extra_lead=True, n_train=2):
    runs = []
    conds = [(40.0, 800.0, "ccw"), (60.0, 1200.0, "cw"), (25.0, 2000.0, "ccw")][: n_train] + [(20.0, 2500.0, "cw")]
    for i, (r, feed, d) in enumerate(conds):
        prog = circle(r, (200.0, 300.0), feed, d, 30.0, 360.0, lead_in_deg=lead_in_deg, lead_out_deg=45.0,
                      acceleration_mm_s2=800.0)
        prog = replace(prog, record_from_s=0.0, record_to_s=prog.duration_s)
        tr = simulate(axes, prog, rate_hz=250.0, rng=rng)
        extra = {"lead_in_deg": lead_in_deg, "lead_out_deg": 45.0} if extra_lead else {}
        run = tr.to_run(f"circle_{i}.csv", split="test" if i == len(conds) - 1 else "train", extra=extra)
        if not cmd:
            run = Run(run.spec, {k: v for k, v in run.columns.items() if not k.endswith("_command_mm")})
        runs.append(run)
    spec = {a: m.to_axis_spec((0.0, 800.0)) for a, m in axes.items()}
    return Dataset(MachineSpec("m", spec), tuple(runs))


@pytest.mark.parametrize("lead_in_deg, given", [(90.0, True), (90.0, False), (0.0, True)])
def test_a_nominal_circle_recorded_with_its_feed_in_is_none_at_the_noise_floor(lead_in_deg, given):
    ds = _circles(_axes(), lead_in_deg, np.random.default_rng(7), extra_lead=given)
    rep = diagnose(ds)
    assert rep.effect == "none"
    assert rep.effects == ()
    assert rep.gap_before_um <= 2.0 * rep.noise_floor_um
    assert rep.program_source == "recorded command columns"


def test_the_data_arc_is_found_from_the_recorded_command():
    ds = _circles(_axes(), 90.0, np.random.default_rng(1), extra_lead=False)
    c = prepare_contour(ds.runs[0], "train", ds.machine.axes)
    arc = c.meta["data_arc"]
    assert arc["lead_in_deg"] == pytest.approx(90.0, abs=0.5)
    assert arc["lead_out_deg"] == pytest.approx(45.0, abs=0.5)
    # scored samples cover the 360° data arc, not the feed-in or the lead-out
    ang = c.angle_deg()
    assert np.ptp(np.unwrap(np.radians(ang))) == pytest.approx(2 * np.pi, abs=0.1)
    assert 0.6 < c.scored.size / c.t_s.size < 0.85


def test_a_dataset_without_command_columns_works_and_says_it_rebuilt_the_program():
    ds = _circles(_axes(), 0.0, np.random.default_rng(3), cmd=False)
    rep = diagnose(ds)
    assert "rebuilt from the run fields" in rep.program_source
    assert "rebuilt" in rep.text()
    assert rep.to_dict()["program_source"].startswith("rebuilt")
    assert np.isfinite(rep.gap_before_um)


def test_two_diagnoses_in_one_process_do_not_share_simulations():
    """Same file names, other machines: each diagnosis equals the one made alone."""
    a = _circles(_axes((40.0, 70.0)), 90.0, np.random.default_rng(11), n_train=1)
    b = _circles(_axes((120.0, 20.0), (30.0, 9.0)), 90.0, np.random.default_rng(12), n_train=1)
    first_a = diagnose(a).to_dict()
    then_b = diagnose(b).to_dict()
    again_a = diagnose(a).to_dict()
    assert again_a == first_a
    assert then_b["nominal_backlash_um"] != first_a["nominal_backlash_um"]
    assert then_b["nominal_backlash_um"]["x"] == pytest.approx(120.0, abs=5.0)


def test_a_second_effect_is_named_when_it_remains():
    """Cyclic error on the round trips and servo lag on the circles: the dominant one is
    named, and the other is reported as the second effect (effects has both)."""
    from core.sim import CyclicError, Effects, ServoDynamics, round_trip

    fx = Effects(cyclic_error=CyclicError.of((16.0, 5.0, 30.0)),
                 servo_dynamics=ServoDynamics(velocity_lag_s=0.006, dead_time_s=0.001))
    axes = {a: AxisModel(name=a, transmission_mm_per_rev=8.0, screw_lead_mm=16.0, position_gain_per_s=12.0,
                         backlash_um=50.0, encoders=ENC, effects=fx) for a in "xy"}
    rng = np.random.default_rng(21)
    runs = []
    for a in "xy":
        for i, (feed, temp) in enumerate(((600.0, 18.0), (1000.0, 20.0), (1500.0, 22.0), (2400.0, 28.0))):
            tr = simulate({a: axes[a]}, round_trip(20.0 + 30 * i, 160.0 + 30 * i, feed, 600.0, 0.3, axis=a),
                          temperature_c=temp, rate_hz=250.0, rng=rng)
            runs.append(tr.to_run(f"rt_{a}{i}.csv", split="test" if i == 3 else "train"))
    ds = _circles(axes, 90.0, rng)
    ds = Dataset(ds.machine, tuple(runs) + ds.runs)
    rep = diagnose(ds, workers=2)
    assert set(rep.effects) == {"cyclic_error", "servo_dynamics"}, rep.text()
    assert rep.effect == rep.effects[0]
    assert rep.second_effect.startswith("A second effect remains: " + rep.effects[1])
    assert rep.to_dict()["pairs"][0]["effect"] == "+".join(rep.effects)
    assert rep.gap_after_um < 0.5 * rep.gap_before_um
