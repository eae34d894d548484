"""The flank contact shared by the twin's dynamic loop and the gap's compliance candidate."""

import math

import pytest

from core.sim.kernels import flank_force


def test_no_force_inside_the_play():
    assert flank_force(0.004, 0.005, 1e5, 10.0, 3.0) == 0.0
    assert flank_force(-0.005, 0.005, 1e5, 10.0, -3.0) == 0.0


def test_spring_damper_on_the_flank_reached():
    # 2 µm into the upper flank at 100 N/µm, closing at 1 mm/s with 50 N s/mm
    assert flank_force(0.007, 0.005, 1e5, 50.0, 1.0) == pytest.approx(1e5 * 0.002 + 50.0)
    assert flank_force(-0.007, 0.005, 1e5, 50.0, -1.0) == pytest.approx(-(1e5 * 0.002 + 50.0))


def test_a_flank_pushes_but_never_pulls():
    # in contact but separating fast: the damper would pull, the contact gives zero
    assert flank_force(0.0051, 0.005, 1e5, 50.0, -10.0) == 0.0
    assert flank_force(-0.0051, 0.005, 1e5, 50.0, 10.0) == 0.0


def test_nan_input_shows_in_the_force():
    assert math.isnan(flank_force(0.007, 0.005, 1e5, 50.0, math.nan))
    assert math.isnan(flank_force(-0.007, 0.005, math.nan, 50.0, 0.0))
