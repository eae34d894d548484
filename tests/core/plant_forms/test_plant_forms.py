"""The second plant: valid, reproducible datasets, a nominal machine that behaves, effects that show."""

import json

import numpy as np
import pytest
from scipy.signal import lfilter

from core.dataset import RUN_KINDS, validate_columns, validate_run_spec
from core.errors import InputError
from core.plant_forms import LABELS, FormsSize, make_forms_case

SIZE = FormsSize(1, 1, 1, 1, 250.0, 200.0, 8.0)
EFFECTS = LABELS[1:]


def _case(labels, seed=11, size=SIZE):
    return make_forms_case(labels, np.random.default_rng(seed), size)


@pytest.fixture(scope="module")
def nominal():
    return _case(("none",))


def _servo_lag_prediction(run, axis, gain_per_s):
    """The table a rigid, backlash-free axis with a P position loop of gain K reaches."""
    t, cmd = run.time_s, run.command_mm(axis)
    up = 50  # the first-order lag solved on a fine grid, the command linear between samples
    t_fine = np.linspace(t[0], t[-1], (len(t) - 1) * up + 1)
    c_fine = np.interp(t_fine, t, cmd)
    g = np.exp(-gain_per_s * (t[1] - t[0]) / up)
    return lfilter([1 - g], [1, -g], c_fine, zi=[g * c_fine[0]])[0][::up]


def _lost_motion_um(case, run, axis):
    k_a = case.dataset.machine.axes[axis].transmission_mm_per_rev
    lm = run.table_mm(axis) - k_a * run.motor_rev(axis)
    return (lm - lm[0]) * 1e3


@pytest.mark.parametrize("labels", [("none",), ()] + [(lab,) for lab in EFFECTS] + [("friction", "sampling_skew")])
def test_every_label_builds_a_dataset_that_passes_validation(labels):
    case = _case(labels)
    ds = case.dataset
    assert set(ds.machine.axes) == {"x", "y"}
    kinds = [r.spec.kind for r in ds.runs]
    assert kinds.count("round_trip") == 4 and kinds.count("circle") == 2
    splits = {r.spec.split for r in ds.runs}
    assert splits in ({None}, {"train", "test"})
    for run in ds.runs:
        assert run.spec.kind in RUN_KINDS
        validate_run_spec(run.spec, ds.machine)
        validate_columns(run.spec, run.columns)
        for a in run.spec.axes:
            for col in (f"{a}_motor_rev", f"{a}_table_mm", f"{a}_command_mm"):
                assert col in run.columns and np.all(np.isfinite(run.columns[col]))
        assert np.all(np.diff(run.time_s) > 0)
        if run.spec.kind == "circle":
            assert run.spec.radius_mm > 0 and run.spec.sweep_deg == 360.0
            assert run.spec.extra["lead_in_deg"] > 0
    assert case.labels == (labels if labels else ("none",))
    json.dumps(case.truth)  # every drawn parameter is plain JSON
    for lab in case.labels:
        if lab != "none":
            assert case.truth["effects"][lab]["form"]


def test_the_same_seed_gives_identical_data_and_another_seed_other_numerics():
    a, b, c = _case(("thermal", "friction"), 5), _case(("thermal", "friction"), 5), _case(("thermal", "friction"), 6)
    assert a.truth == b.truth
    for ra, rb in zip(a.dataset.runs, b.dataset.runs):
        assert ra.spec == rb.spec
        for name in ra.columns:
            np.testing.assert_array_equal(ra.columns[name], rb.columns[name])
    assert a.truth["machine"]["x"]["backlash_um"] != c.truth["machine"]["x"]["backlash_um"]
    assert a.truth["rt_rate_hz"] != c.truth["rt_rate_hz"]


def test_numerics_vary_within_their_ranges():
    for seed in range(4):
        t = _case((), seed).truth
        assert 0.8 * SIZE.rt_rate_hz <= t["rt_rate_hz"] <= 1.2 * SIZE.rt_rate_hz
        assert 0.8 * SIZE.circle_rate_hz <= t["circle_rate_hz"] <= 1.2 * SIZE.circle_rate_hz
        for ax in t["machine"].values():
            assert 5.0 <= ax["backlash_um"] <= 150.0
            assert 5.0 <= ax["screw_lead_mm"] <= 20.0
            assert 15.0 <= ax["position_gain_per_s"] <= 60.0
            assert 2**13 <= ax["motor_counts_per_rev"] <= 2**20
            assert 0.05 <= ax["scale_quantum_um"] <= 1.0


def test_a_nominal_table_follows_the_command_within_backlash_and_servo_lag(nominal):
    for run in nominal.dataset.runs:
        for a in run.spec.axes:
            truth = nominal.truth["machine"][a]
            b_um = truth["backlash_um"]
            lag_um = np.abs(run.command_mm(a) - _servo_lag_prediction(run, a, truth["position_gain_per_s"])).max() * 1e3
            residual_um = (run.table_mm(a) - _servo_lag_prediction(run, a, truth["position_gain_per_s"])) * 1e3
            assert lag_um > 100.0  # the lag is what explains most of table minus command
            assert np.abs(residual_um).max() <= 1.2 * b_um + 15.0, (run.spec.file, a)
            # Lost motion: the gap plus the nut's deflection under the largest drive force, both ways.
            force_n = (truth["coulomb_n"] + truth["viscous_n_s_per_m"] * run.spec.feed_mm_min / 60e3
                       + truth["table_kg"] * nominal.truth["max_accel_mm_s2"] * 1e-3)
            lm_range_um = np.ptp(_lost_motion_um(nominal, run, a))
            assert 0.8 * b_um <= lm_range_um <= 1.2 * b_um + 2 * force_n / truth["nut_stiffness_n_per_um"] + 15.0


@pytest.mark.parametrize("label", EFFECTS)
def test_each_effect_changes_the_trajectory_against_the_same_nominal_machine(label, nominal):
    case = _case((label,))
    assert case.truth["machine"] == nominal.truth["machine"]
    noise_um = max(max(ax["scale_noise_um"], ax["motor_noise_um"]) for ax in nominal.truth["machine"].values())
    change_um = 0.0
    for run in nominal.dataset.runs:
        other = case.dataset.run(run.spec.file)
        for a in run.spec.axes:
            d_table = np.abs(other.table_mm(a) - run.table_mm(a)).max() * 1e3
            d_lost = np.abs(_lost_motion_um(case, other, a) - _lost_motion_um(nominal, run, a)).max()
            change_um = max(change_um, d_table, d_lost)
    # A full-closed loop follows its scale: an effect in the chain may show only in
    # table minus motor (the lost motion), so the larger of both changes is compared.
    assert change_um > 5 * noise_um + 1.0, (label, case.truth["effects"][label], change_um)


def test_split_is_marked_in_about_two_thirds_of_the_datasets():
    tiny = FormsSize(0, 0, 1, 1, 250.0, 100.0, 3.0)
    marked = [_case((), seed, tiny).dataset.runs[0].spec.split is not None for seed in range(30)]
    assert 12 <= sum(marked) <= 28


@pytest.mark.parametrize("labels", [("bogus",), ("none", "thermal"), ("thermal", "thermal"),
                                    ("thermal", "friction", "compliance")])
def test_labels_outside_the_list_or_more_than_two_are_refused(labels):
    with pytest.raises(InputError, match="label"):
        _case(labels)


def test_a_size_without_a_positive_rate_is_refused():
    with pytest.raises(InputError, match="rt_rate_hz"):
        _case((), size=FormsSize(1, 1, 1, 1, 0.0, 200.0, 8.0))


def test_the_benchmark_draws_its_cases_from_the_plant_without_diagnosing_them():
    # the plant is held out: the harness can generate its cases, and this test looks at
    # no diagnosis of them
    from core.gap_benchmark import PLANTS, SMALL, benchmark_case

    assert "forms" in PLANTS
    labs, ds, truth = benchmark_case("forms", 4, 7, 1, SMALL)
    assert set(ds.machine.axes) == {"x", "y"} and ds.runs
    assert tuple(truth["labels"]) == (labs or ("none",))
