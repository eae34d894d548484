"""The train score of envelope-scored round-trip models (chains that stick-slip or hunt):
a slow stick-slip with the right amplitude and rate but another phase is judged over
250 ms by its envelope as well, so a model that damps the motion out gains less over it
than it does on the 50 ms score alone; white noise keeps its RMS."""

import dataclasses

import numpy as np
import pytest

from core.gap.data import RoundTrip
from core.gap.roundtrip import residual_env_um, residual_train_env_um, rms

RATE_HZ = 250.0


def _run(x_mm: np.ndarray, u_mm: np.ndarray) -> RoundTrip:
    t = np.arange(x_mm.size) / RATE_HZ
    return RoundTrip("rt.csv", "x", "train", t, u_mm, x_mm, 20.0, 1000.0, None, 1, np.arange(x_mm.size))


def _score(fn, pred, run):
    return rms(fn(pred, run, run.fit_idx, stacked=True))  # compared as ratios only


def test_a_slow_stick_slip_out_of_phase_is_penalised_less_against_a_damped_out_model():
    t = np.arange(int(4.0 * RATE_HZ)) / RATE_HZ
    u = 10.0 * t  # mm, a stroke at 600 mm/min
    slip = lambda phase: 0.010 * np.sin(2 * np.pi * 6.0 * t + phase)  # noqa: E731 - 10 µm at 6 Hz
    run = _run(u + slip(0.0), u)
    out_of_phase, damped = u + slip(2.0), u.copy()
    ratio_50 = _score(residual_env_um, out_of_phase, run) / _score(residual_env_um, damped, run)
    ratio_train = _score(residual_train_env_um, out_of_phase, run) / _score(residual_train_env_um, damped, run)
    assert ratio_50 > 1.3  # sample by sample below 20 Hz the damped-out model wins clearly
    assert ratio_train < 0.8 * ratio_50


def test_white_noise_keeps_its_rms_in_the_train_score():
    rng = np.random.default_rng(1)
    t = np.arange(int(4.0 * RATE_HZ)) / RATE_HZ
    u = 10.0 * t
    run = _run(u + 1e-3 * rng.normal(size=t.size), u)
    plain = rms(residual_train_env_um(u, run, run.fit_idx))
    assert 0.8 < plain < 1.2


def test_a_copy_of_a_run_keeps_nothing_of_the_original_memo():
    """What a run computes once (its sample step, the record's envelope split) is kept per
    run: a copy with other times or another record computes its own."""
    t = np.arange(int(2.0 * RATE_HZ)) / RATE_HZ
    u = 10.0 * t
    run = _run(u + 0.002 * np.sin(2 * np.pi * 40.0 * t), u)
    assert run.dt_s == pytest.approx(1.0 / RATE_HZ)
    first = residual_env_um(u, run)
    faster = dataclasses.replace(run, t_s=t / 2.0)  # the same samples at twice the rate
    assert faster.dt_s == pytest.approx(0.5 / RATE_HZ) and run.dt_s == pytest.approx(1.0 / RATE_HZ)
    quiet = dataclasses.replace(run, x_mm=u.copy())  # the same times, no ripple recorded
    assert rms(residual_env_um(u, quiet)) < 1e-9 < 0.5 * rms(first)
    np.testing.assert_array_equal(residual_env_um(u, run), first)
