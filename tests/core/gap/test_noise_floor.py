"""The noise floor is the RMS a test gap of white noise alone would have: the decision
compares the (RMS) test gap against it. Round-trip axes, whose encoders differ, each count
with their own level; contours with the level of every run pooled; levels are read from
third differences, which a chain's own smooth motion does not reach."""

import importlib

import numpy as np
import pytest

dg = importlib.import_module("core.gap.diagnose")  # core.gap.diagnose is also the function


def _rms(runs) -> float:
    return float(np.sqrt(np.mean(np.concatenate(runs) ** 2)))


def test_one_noise_level_is_read_as_it_is():
    rng = np.random.default_rng(3)
    runs = [0.3 * rng.standard_normal(20000) for _ in range(3)]
    assert dg.noise_floor_um(runs) == pytest.approx(0.3, rel=0.03)
    assert dg.noise_floor_um(runs, ["x", "x", None]) == pytest.approx(0.3, rel=0.03)


def test_axes_of_different_noise_give_the_rms_of_the_noise_not_the_quieter_axis():
    """x's encoders 0.40 µm, y's 0.08 µm (the independent plant's seed 8311, case 48): the
    level of the pooled differences reads near y's, half the RMS of the noise."""
    rng = np.random.default_rng(4)
    x, y = 0.40 * rng.standard_normal(30000), 0.08 * rng.standard_normal(30000)
    circle = 0.1 * rng.standard_normal(2000)
    floor = dg.noise_floor_um([x, y, circle], ["x", "y", None])
    assert floor == pytest.approx(_rms([x, y, circle]), rel=0.05)
    pooled = dg.noise_floor_um([x, y, circle])
    assert pooled < 0.7 * floor  # one median over all axes: a gap of noise alone at 2x it


@pytest.mark.parametrize("seed", range(5))
def test_white_noise_of_any_levels_per_axis_stays_at_its_floor(seed):
    rng = np.random.default_rng(seed)
    level = {"x": rng.uniform(0.05, 0.6), "y": rng.uniform(0.05, 0.6), "z": rng.uniform(0.05, 0.6)}
    axes = [str(a) for a in rng.choice(list(level), int(rng.integers(2, 9)))]
    runs = [level[a] * rng.standard_normal(int(rng.integers(1500, 30000))) for a in axes]
    assert 0.95 < _rms(runs) / dg.noise_floor_um(runs, axes) < 1.05


def test_a_stroke_that_stick_slips_throughout_does_not_raise_its_axis_level():
    """A chain that rattles through the whole test stroke, 15 µm at 60 Hz sampled at 2 kHz
    (smooth between samples), with a sharp slip of 20 µm every 0.5 s. First differences
    read it as noise of µm (on the independent plant's seed 6060 case 28: 7.17 µm where
    the encoders' was 0.33 µm); third differences leave the smooth motion out and pass the
    slips, a few samples each, through the median."""
    rng = np.random.default_rng(7)
    t = np.arange(20000) / 2000.0
    motion = 15.0 * np.sin(2 * np.pi * 60.0 * t) + 20.0 * np.floor(t / 0.5)
    stroke = 0.2 * rng.standard_normal(t.size) + motion
    quiet = 0.1 * rng.standard_normal(20000)
    assert dg.white_level_um([stroke], order=1) > 5 * 0.2
    assert dg.noise_floor_um([stroke]) == pytest.approx(0.2, rel=0.1)
    floor = dg.noise_floor_um([stroke, quiet], ["x", "y"])
    assert floor == pytest.approx(np.sqrt((0.2**2 + 0.1**2) / 2), rel=0.1)


def test_contours_take_the_pooled_level():
    """A sparse contour whose radial error has a spike after each reversal (4 of 1500
    samples wide) beside the round trips of both axes: it counts at every run's level."""
    rng = np.random.default_rng(8)
    rt = [0.25 * rng.standard_normal(29000), 0.11 * rng.standard_normal(29000)]
    n = np.arange(1500)
    circle = 0.15 * rng.standard_normal(n.size) + sum(30.0 * np.exp(-0.5 * ((n - c) / 1.5) ** 2) for c in (200, 575, 950, 1325))
    pooled = dg.white_level_um([*rt, circle])
    floor = dg.noise_floor_um([*rt, circle], ["x", "y", None])
    weights = np.array([29000, 29000, 1500])
    levels = np.array([dg.white_level_um([rt[0]]), dg.white_level_um([rt[1]]), pooled])
    assert floor == pytest.approx(np.sqrt(np.sum(weights * levels**2) / weights.sum()), rel=1e-9)
    assert floor == pytest.approx(_rms([*rt, 0.15 * rng.standard_normal(1500)]), rel=0.1)


def test_the_contour_gate_keeps_first_differences():
    rng = np.random.default_rng(9)
    r = [0.3 * rng.standard_normal(4000)]
    assert dg.white_level_um(r, order=1) == pytest.approx(0.3, rel=0.05)
    d = np.diff(r[0])
    assert dg.white_level_um(r, order=1) == pytest.approx(np.median(np.abs(d - np.median(d))) / 0.6745 / np.sqrt(2))


def test_slow_motion_and_steps_do_not_raise_it():
    rng = np.random.default_rng(5)
    t = np.linspace(0.0, 10.0, 20000)
    r = 0.2 * rng.standard_normal(t.size) + 30.0 * np.sin(0.5 * t) + np.where(t > 5.0, 50.0, 0.0)
    assert dg.noise_floor_um([r]) == pytest.approx(0.2, rel=0.05)
    assert dg.noise_floor_um([r], ["x"]) == pytest.approx(0.2, rel=0.05)


def test_runs_too_short_to_difference_are_left_out():
    assert dg.noise_floor_um([]) == 0.0
    assert dg.noise_floor_um([np.array([1.0, 2.0, 3.0, 4.0])], ["x"]) == 0.0  # no third difference
    rng = np.random.default_rng(6)
    runs = [np.array([5.0, -5.0, 5.0]), 0.1 * rng.standard_normal(5000)]
    assert dg.noise_floor_um(runs, ["x", "y"]) == pytest.approx(0.1, rel=0.05)


def test_a_quantized_record_reads_its_step_and_adds_it_beside_the_white_level():
    rng = np.random.default_rng(5)
    t = np.linspace(0.0, 10.0, 10001)
    path_mm = 5.0 * np.clip(t - 1.0, 0.0, 8.0)  # at rest, then 5 mm/s, then at rest: a stroke
    x = np.round((path_mm + 0.0002 * rng.standard_normal(t.size)) / 1e-3) * 1e-3  # mm, a 1 µm scale
    assert dg.step_um(x) == pytest.approx(1.0, rel=1e-6)
    assert dg.step_um(path_mm + 1e-4 * rng.standard_normal(t.size)) < 0.01  # an unquantized record
    assert dg.step_um(np.zeros(5)) == 0.0
    # 1 µm on the table, 2^16 counts of a 10 mm-per-revolution motor: 0.15 µm
    u = np.round((path_mm + 1e-4 * rng.standard_normal(t.size)) / (10.0 / 2**16)) * (10.0 / 2**16)
    assert dg.quantization_um(x, u) == pytest.approx(np.hypot(1.0, 10e3 / 2**16) / np.sqrt(12.0), rel=1e-3)
    # a slowly moving quantized residual: its differences read almost nothing, the step 0.29 µm
    resid = [np.round(np.sin(np.linspace(0.0, 3.0, 20000)) * 2.0) * 1.0]  # µm, steps of 1 µm
    assert dg.noise_floor_um(resid) < 0.05
    with_q = dg.noise_floor_um(resid, ["x"], [dg.quantization_um(x)])
    assert with_q == pytest.approx(1.0 / np.sqrt(12.0), rel=0.1)
    assert dg.noise_floor_um(resid, None, [0.0]) == pytest.approx(dg.noise_floor_um(resid))
