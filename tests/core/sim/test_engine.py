"""simulate(): input checks and the trace's dataset view."""

import numpy as np
import pytest

from core.dataset import AxisSpec
from core.errors import InputError
from core.gap.contour import SIM_STEP_S, SIM_STEPS_PER_RADIAN
from core.sim import AxisModel, Compliance, Effects, Friction, Thermal, circle, round_trip, simulate


@pytest.mark.parametrize(
    ("kwargs", "named"),
    [
        ({"rate_hz": 0.0}, "rate_hz"),
        ({"rate_hz": 1e6}, "lower rate_hz"),
        ({"step_s": -1.0}, "step_s"),
        ({"temperature_c": float("nan")}, "temperature_c"),
        ({"steps_per_radian": 0.0}, "steps_per_radian"),
    ],
)
def test_bad_settings_raise_input_error_naming_them(kwargs, named):
    with pytest.raises(InputError, match=named):
        simulate({"y": AxisModel()}, round_trip(0.0, 600.0, 100.0), **kwargs)


def test_every_program_axis_needs_a_model():
    with pytest.raises(InputError, match=r"\['x'\]"):
        simulate({"y": AxisModel()}, circle(10.0, feed_mm_min=100.0))


def test_axis_model_validates_and_converts_to_and_from_axis_spec():
    spec = AxisSpec("z", 5.0, 10.0, 20.0, (0.0, 300.0))
    model = AxisModel.from_axis_spec(spec, backlash_um=40.0, effects=Effects(thermal=Thermal()))
    assert (model.name, model.transmission_mm_per_rev, model.position_gain_per_s, model.backlash_um) == (
        "z", 5.0, 20.0, 40.0,
    )  # fmt: skip
    assert model.to_axis_spec((0.0, 300.0)) == spec
    with pytest.raises(InputError, match="backlash_um"):
        AxisModel(backlash_um=-1.0)
    with pytest.raises(InputError, match="initial_side"):
        AxisModel(initial_side="up")


def test_to_run_gives_the_dataset_columns_and_circle_metadata():
    axes = {a: AxisModel(a) for a in ("x", "y")}
    tr = simulate(axes, circle(20.0, (1.0, 2.0), 600.0, "cw", 0.0, 90.0), temperature_c=25.0, rate_hz=50.0)
    run = tr.to_run("c.csv", split="train", utility_day=4.0, extra={"operator": "sim"})
    assert list(run.columns) == [
        "time_s", "x_command_mm", "x_motor_rev", "x_table_mm", "y_command_mm", "y_motor_rev", "y_table_mm",
    ]  # fmt: skip
    s = run.spec
    assert (s.kind, s.axes, s.radius_mm, s.centre_mm, s.direction, s.start_angle_deg, s.sweep_deg) == (
        "circle", ("x", "y"), 20.0, (1.0, 2.0), "cw", 0.0, 90.0,
    )  # fmt: skip
    assert (s.temperature_c, s.split, s.utility_day, s.extra["operator"]) == (25.0, "train", 4.0, "sim")
    assert np.all(np.diff(run.time_s) > 0)


@pytest.mark.parametrize("effects", [
    Effects(friction=Friction(coulomb_n=1600.0, static_n=2000.0, stribeck_velocity_mm_s=2.0, model="lugre",
                              bristle_stiffness_n_per_um=3200.0)),  # 0.5 µm pre-sliding: the stiffest fitted
    Effects(compliance=Compliance(stiffness_n_per_um=790.0, table_mass_kg=500.0, damping_ratio=0.05)),  # 200 Hz
])  # fmt: skip
def test_fewer_steps_per_radian_take_longer_steps_and_stay_within_hundredths_of_a_micrometre(effects):
    """The gap diagnosis simulates at its own steps per radian (core.gap.contour, 10): the
    step it takes is longer than the twin's and the table moves by under 0.02 µm RMS."""
    axes = {a: AxisModel(a, backlash_um=10.0, effects=effects) for a in ("x", "y")}
    prog = circle(50.0, feed_mm_min=2000.0, lead_in_deg=90.0)
    fine = simulate(axes, prog, rate_hz=500.0, step_s=SIM_STEP_S)
    coarse = simulate(axes, prog, rate_hz=500.0, step_s=SIM_STEP_S, steps_per_radian=SIM_STEPS_PER_RADIAN)
    for a in ("x", "y"):
        assert coarse.step_s[a] > 1.5 * fine.step_s[a]
        d_um = (coarse.table_true_mm[a] - fine.table_true_mm[a]) * 1e3
        assert np.sqrt(np.mean(d_um**2)) < 0.02
        assert np.max(np.abs(d_um)) < 0.3
