"""Min/max downsampling keeps every excursion and bounds the point count."""

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from core.downsample import minmax_indices
from core.errors import InputError


def test_a_single_spike_in_a_year_of_minutes_survives():
    y = np.full(525_600, 200.0)
    y[123_457] = 260.0  # the one alert-level measurement
    y[400_001] = 150.0
    idx = minmax_indices(y, 2000)
    assert idx.size <= 2000 and 123_457 in idx and 400_001 in idx and idx[0] == 0 and idx[-1] == y.size - 1


@given(st.lists(st.floats(-1e6, 1e6), min_size=0, max_size=400), st.integers(4, 100))
def test_indices_are_sorted_unique_bounded_and_keep_the_extremes(values, max_points):
    y = np.asarray(values, float)
    idx = minmax_indices(y, max_points)
    assert idx.size <= max_points
    assert np.all(np.diff(idx) > 0)
    if y.size:
        assert y[idx].min() == y.min() and y[idx].max() == y.max()


def test_nan_is_not_chosen_over_a_number():
    y = np.array([1.0, np.nan, np.nan, 5.0, np.nan, 2.0, 3.0, np.nan, 0.5, 4.0] * 10)
    idx = minmax_indices(y, 10)
    assert np.isfinite(y[idx[1:-1]]).all()


def test_max_points_is_checked():
    with pytest.raises(InputError, match="max_points"):
        minmax_indices([1.0, 2.0], 3)
