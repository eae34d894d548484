"""Datasets of the independent plant: format, layout draws, case structure, independence."""

import ast
from pathlib import Path

import numpy as np
import pytest

import core.plant_independent as plant
from core.dataset import validate_columns, validate_run_spec
from core.errors import InputError
from core.plant_independent import LABELS, SMALL_PLANT, PlantCase, PlantSize, make_plant_case
from core.plant_independent.case import draw_layout


@pytest.fixture(scope="module")
def cases() -> dict[tuple, PlantCase]:
    out = {}
    for seed, labels in enumerate([(), ("friction", "thermal"), ("sampling_skew",), ("servo_dynamics",)]):
        out[labels] = make_plant_case(labels, np.random.default_rng([11, seed]), SMALL_PLANT)
    return out


def test_api_constants():
    assert LABELS == ("none", "thermal", "backlash_profile", "cyclic_error", "friction", "compliance",
                      "servo_dynamics", "sampling_skew")  # fmt: skip
    assert PlantSize() == PlantSize(3, 1, 4, 2, 1000.0, 500.0, 30.0)
    assert SMALL_PLANT.rt_train_per_axis == 2 and SMALL_PLANT.circles_test == 1


def test_datasets_validate_and_carry_every_column(cases):
    for labels, case in cases.items():
        ds = case.dataset
        assert case.labels == labels
        assert set(ds.machine.axes) == {"x", "y"}
        for ax in ds.machine.axes.values():
            assert 8.0 <= ax.position_gain_per_s <= 40.0 and ax.travel_mm == (0.0, 800.0)
        for run in ds.runs:
            validate_run_spec(run.spec, ds.machine)
            validate_columns(run.spec, run.columns)
            for a in run.spec.axes:
                assert run.command_mm(a) is not None
            assert run.time_s[0] > 0.5  # a controller clock, not zero
            rate = SMALL_PLANT.rt_rate_hz if run.spec.kind == "round_trip" else SMALL_PLANT.circle_rate_hz
            assert np.allclose(np.diff(run.time_s), 1.0 / rate)
        kinds = [r.spec.kind for r in ds.runs]
        n_rt = (SMALL_PLANT.rt_train_per_axis + SMALL_PLANT.rt_test_per_axis) * 2
        assert kinds == ["round_trip"] * n_rt + ["circle"] * (SMALL_PLANT.circles_train + SMALL_PLANT.circles_test)


def test_test_runs_lie_outside_the_train_temperatures(cases):
    for case in cases.values():
        n_tr = SMALL_PLANT.rt_train_per_axis
        rts = [r for r in case.dataset.runs if r.spec.kind == "round_trip"]
        per_axis = [rts[: len(rts) // 2], rts[len(rts) // 2 :]]
        for runs in per_axis:
            assert all(16.5 <= r.spec.temperature_c <= 24.5 for r in runs[:n_tr])
            assert all(r.spec.temperature_c <= 12 or r.spec.temperature_c >= 28 for r in runs[n_tr:])
        splits = {r.spec.split for r in case.dataset.runs}
        assert splits in ({None}, {"train", "test"})
        if splits == {"train", "test"}:
            test_temps = [r.spec.temperature_c for r in case.dataset.runs if r.spec.split == "test"]
            assert all(t <= 12 or t >= 28 for t in test_temps)


def test_a_third_without_split_and_half_with_lead_fields():
    rng = np.random.default_rng(3)
    layouts = [draw_layout(rng) for _ in range(3000)]
    assert abs(np.mean([not x.has_split for x in layouts]) - 1 / 3) < 0.03
    assert abs(np.mean([x.writes_lead for x in layouts]) - 1 / 2) < 0.03


def test_circles_have_feed_in_and_lead_out_of_random_length(cases):
    seen_in, seen_out = [], []
    for case in cases.values():
        written = case.truth["layout"]["writes_lead"]
        for run, drawn in zip([r for r in case.dataset.runs if r.spec.kind == "circle"], case.truth["circles"]):
            assert run.spec.sweep_deg == 360.0 and run.spec.file == drawn["file"]
            assert ("lead_in_deg" in run.spec.extra) == written
            if written:
                assert run.spec.extra["lead_in_deg"] == drawn["lead_in_deg"]
            seen_in.append(drawn["lead_in_deg"])
            seen_out.append(drawn["lead_out_deg"])
            # the data arc starts where the feed-in ends: the recording spans all of it
            cx, cy = run.spec.centre_mm
            x, y = run.command_mm("x") - cx, run.command_mm("y") - cy
            a0 = np.rad2deg(np.arctan2(y[0], x[0]))
            sgn = 1.0 if run.spec.direction == "ccw" else -1.0
            expect = run.spec.start_angle_deg - sgn * drawn["lead_in_deg"]
            assert abs((a0 - expect + 180.0) % 360.0 - 180.0) < 1e-6
            turned = np.sum(np.diff(np.unwrap(np.arctan2(y, x)))) * sgn
            assert np.isclose(np.rad2deg(turned), 360.0 + drawn["lead_in_deg"] + drawn["lead_out_deg"], atol=1e-6)
    assert all(0.0 <= v <= 180.0 for v in seen_in + seen_out)
    assert len(set(np.round(seen_in, 6))) > 3


def test_split_field_absent_in_some_datasets():
    has = [make_plant_case((), np.random.default_rng([5, s]), PlantSize(1, 1, 1, 1, 50.0, 50.0, 6.0)) for s in range(6)]
    flags = {case.truth["layout"]["has_split"] for case in has}
    assert flags == {True, False}
    for case in has:
        splits = {r.spec.split for r in case.dataset.runs}
        assert splits == ({"train", "test"} if case.truth["layout"]["has_split"] else {None})


def test_truth_holds_each_axis_draw_and_one_shared_skew(cases):
    mixed = cases[("friction", "thermal")]
    for a in ("x", "y"):
        assert {"nominal", "friction", "thermal", "drive"} <= set(mixed.truth[a])
        assert mixed.truth[a]["friction"]["form"] in ("karnopp", "dahl")
    assert mixed.truth["x"]["thermal"] != mixed.truth["y"]["thermal"]  # own draws per axis
    skew = cases[("sampling_skew",)]
    assert skew.truth["x"]["sampling_skew"] is skew.truth["y"]["sampling_skew"]
    none = cases[()]
    assert set(none.truth["x"]) == {"nominal", "drive"}


def test_labels_are_checked():
    rng = np.random.default_rng(0)
    for bad in (("nope",), ("thermal", "thermal"), ("thermal", "friction", "compliance"), ("none", "thermal")):
        with pytest.raises(InputError):
            make_plant_case(bad, rng, SMALL_PLANT)


def test_the_plant_imports_neither_the_twin_nor_the_diagnosis():
    root = Path(plant.__file__).parent
    for path in root.glob("*.py"):
        tree = ast.parse(path.read_text())
        for node in ast.walk(tree):
            names = []
            if isinstance(node, ast.Import):
                names = [a.name for a in node.names]
            elif isinstance(node, ast.ImportFrom) and node.level == 0:
                names = [node.module or ""]
            for n in names:
                if n.startswith("core"):
                    assert n in ("core.dataset", "core.errors"), f"{path.name} imports {n}"


def test_truth_is_plain_json(cases):
    import json

    for case in cases.values():
        back = json.loads(json.dumps(case.truth))
        assert back["labels"] == list(case.labels)
