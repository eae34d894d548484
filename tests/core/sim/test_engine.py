"""simulate(): input checks and the trace's dataset view."""

import numpy as np
import pytest

from core.dataset import AxisSpec
from core.errors import InputError
from core.sim import AxisModel, Effects, Thermal, circle, round_trip, simulate


@pytest.mark.parametrize(
    ("kwargs", "named"),
    [
        ({"rate_hz": 0.0}, "rate_hz"),
        ({"rate_hz": 1e6}, "lower rate_hz"),
        ({"step_s": -1.0}, "step_s"),
        ({"temperature_c": float("nan")}, "temperature_c"),
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
