import numpy as np
import pytest

from core.errors import InputError, NotFittedError
from core.history import TemperatureModel, correlation_table, pearson_r

# Table 2 of the seed paper
DAY = np.array([0, 9, 26, 36, 58, 85, 118, 180, 215], float)
TEMP_C = np.array([7, 9, 5, 9, 15, 21, 23, 19, 10], float)


def test_pearson_matches_definition_eq_4():
    x = DAY
    y = TEMP_C
    expected = np.cov(x, y, ddof=1)[0, 1] / (np.std(x, ddof=1) * np.std(y, ddof=1))
    assert pearson_r(x, y) == pytest.approx(expected, rel=1e-12)


def test_pearson_undefined_cases_are_none():
    assert pearson_r([1.0, 2.0], [3.0, 4.0]) is None
    assert pearson_r([1.0, 1.0, 1.0], [3.0, 4.0, 5.0]) is None
    with pytest.raises(InputError):
        pearson_r([1.0, np.nan, 2.0], [1.0, 2.0, 3.0])


def test_backlash_following_temperature_is_seen_as_such():
    rng = np.random.default_rng(3)
    b = 200 + 2.5 * (TEMP_C - 20) + rng.normal(0, 1.0, TEMP_C.size)
    table = correlation_table({"backlash_mean_um": b}, {"utility_day": DAY, "temperature_c": TEMP_C})
    assert table["backlash_mean_um"]["temperature_c"] > 0.9
    assert abs(table["backlash_mean_um"]["utility_day"]) < table["backlash_mean_um"]["temperature_c"]


def test_temperature_model_recovers_slope_and_normalises():
    rng = np.random.default_rng(4)
    b = 230 + 1.8 * (TEMP_C - 20) + rng.normal(0, 0.2, TEMP_C.size)
    m = TemperatureModel().fit(TEMP_C, b)
    assert m.beta_um_per_k_ == pytest.approx(1.8, abs=0.1)
    assert m.backlash_ref_um_ == pytest.approx(230, abs=0.5)
    assert m.normalise_um(b, TEMP_C) == pytest.approx(np.full(b.size, 230.0), abs=1.0)
    assert float(m.predict_um(30.0)) == pytest.approx(248, abs=1.5)


def test_temperature_model_errors():
    with pytest.raises(NotFittedError):
        TemperatureModel().predict_um(20.0)
    with pytest.raises(InputError, match="two or more temperatures"):
        TemperatureModel().fit([20.0, 20.0, 20.0], [1.0, 2.0, 3.0])
