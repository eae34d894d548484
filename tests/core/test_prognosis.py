"""Prognosis from history: the Huber fit of b̄(T, d) and its answers."""

import math

import numpy as np
import pytest

from core.errors import InputError
from core.prognosis import DAY_S, PrognosisSettings, fit_thermal_wear, prognosis
from core.tbe import MachiningTask, decide

B20, BETA, GAMMA = 20.0, 0.5, 0.01  # µm, µm/K, µm/day
TASK = MachiningTask(name="r50", profile="circle", radius_mm=50.0, feed_mm_min=1000.0, gain_per_s=10.0,
                     tolerance_um=20.0)  # backlash limit 25.7 µm


def _history(seed, n=200, days=300.0, temp=(17.0, 27.0), noise_um=0.3, outliers=5):
    rng = np.random.default_rng(seed)
    d = np.sort(rng.uniform(0, days, n))
    t = rng.uniform(*temp, n)
    b = B20 + BETA * (t - 20.0) + GAMMA * d + rng.normal(0, noise_um, n)
    b[rng.choice(n, outliers, replace=False)] += 10.0  # a few bad cycles the Huber loss must shrug off
    return t, d, b


@pytest.mark.parametrize("seed", [1, 2, 3])
def test_the_fit_recovers_beta_and_gamma_within_their_intervals(seed):
    fit = fit_thermal_wear(*_history(seed))
    assert fit.identifiable and fit.wear_identifiable
    for est, truth in ((fit.beta_um_per_k, BETA), (fit.gamma_um_per_day, GAMMA), (fit.backlash_20c_um, B20)):
        assert est.low <= truth <= est.high
        assert est.high - est.low < 0.2 * abs(truth) + 1.0  # and the intervals are informative
    assert fit.outliers_downweighted >= 5


def test_a_single_temperature_is_not_identifiable():
    t, d, b = _history(4, temp=(21.0, 21.0))
    fit = fit_thermal_wear(t, d, b)
    assert not fit.identifiable and "not identifiable" not in fit.reason  # the reason is specific
    assert "temperature range" in fit.reason
    p = prognosis(fit, [TASK], worst_case_temperature_c=30.0, now_s=0.0)
    d = p.to_dict()
    assert d["identifiable"] is False and d["limit_date"] is None and d["alarm_temperature_c"] is None
    assert "temperature range" in d["limit_date_reason"]
    few = fit_thermal_wear(*(a[:5] for a in _history(4)))
    assert not few.identifiable and "too few cycles" in few.reason


def test_temperature_and_age_moving_together_is_not_identifiable():
    d = np.linspace(0, 200, 50)
    t = 15.0 + d / 20.0
    fit = fit_thermal_wear(t, d, B20 + BETA * (t - 20) + GAMMA * d)
    assert not fit.identifiable and "move together" in fit.reason


def test_a_short_history_fits_beta_but_gives_no_date():
    t, d, b = _history(5, days=10.0)
    fit = fit_thermal_wear(t, d, b)
    assert fit.identifiable and not fit.wear_identifiable and fit.gamma_um_per_day.value == 0.0
    p = prognosis(fit, [TASK], worst_case_temperature_c=24.0, now_s=0.0, day_now=10.0)
    assert p.limit_date_s is None and "wear is not identifiable" in p.limit_date_reason


def test_alarm_temperature_and_limit_date_agree_with_the_decision_rule():
    t, d, b = _history(6, noise_um=0.3, outliers=0)
    fit = fit_thermal_wear(t, d, b)
    limit = TASK.backlash_limit_um()
    day_now = 300.0
    p = prognosis(fit, [TASK], worst_case_temperature_c=22.0, now_s=1e9, day_now=day_now,
                  backlash_uncertainty_um=2.0, rule="guarded")
    assert p.backlash_limit_um == pytest.approx(limit) and p.binding_task == "r50"
    # just above the answer the guarded rule says ALARM on the fitted b̄, just below it does not
    for dt, state in ((+0.01, "ALARM"), (-0.01, None)):
        b_at = float(fit.predict_um(p.alarm_temperature_c + dt, day_now)[0])
        got = decide(b_at, [TASK], backlash_uncertainty_um=2.0, rule="guarded").state.value
        assert (got == "ALARM") == (state == "ALARM")
    # the limit temperature: the true one lies in its interval
    truth_t = 20.0 + (limit - B20 - GAMMA * day_now) / BETA
    assert p.limit_temperature_c.low <= truth_t <= p.limit_temperature_c.high
    # the date at 22 °C: b20 + 2 β + γ d = limit
    truth_day = (limit - B20 - BETA * 2.0) / GAMMA
    lo, hi = p.limit_date_interval_s
    expect_s = 1e9 + (truth_day - day_now) * DAY_S
    if truth_day > day_now:
        assert lo <= expect_s <= hi and p.limit_date_s == pytest.approx(expect_s, rel=0.05)


def test_not_within_the_horizon():
    t, d, b = _history(7, outliers=0)
    fit = fit_thermal_wear(t, d, B20 - 10.0 + BETA * (t - 20) + 0.0 * d + 0.3 * np.sin(d))
    p = prognosis(fit, [TASK], worst_case_temperature_c=25.0, now_s=0.0, day_now=300.0)
    assert p.limit_date_s is None and p.limit_date_reason.startswith("not within 5 years")
    with pytest.raises(InputError):
        prognosis(fit, [TASK], worst_case_temperature_c=math.nan, now_s=0.0)
    with pytest.raises(InputError):
        PrognosisSettings(confidence=1.5)


def test_a_warm_shop_past_eq_8s_domain_counts_as_alarm():
    # a small fast circle: b̄ at 80 °C lies beyond Eq. 8's validity; the bisection must not fail there
    small = MachiningTask(name="r5", profile="circle", radius_mm=5.0, feed_mm_min=2226.5, gain_per_s=5.0,
                          tolerance_um=10.0)  # backlash limit 10.2 µm
    t, d, b = _history(8, outliers=0)
    fit = fit_thermal_wear(t, d, b - 15.0)  # b̄20 = 5 µm, β = 0.5 µm/K
    p = prognosis(fit, [small], worst_case_temperature_c=30.0, now_s=0.0, day_now=0.0, rule="simple")
    truth_t = 20.0 + (small.backlash_limit_um() - 5.0) / BETA
    assert p.alarm_temperature_c == pytest.approx(truth_t, abs=0.5)
