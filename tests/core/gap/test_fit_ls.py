"""The least-squares fits of the gap diagnosis survive a simulation that diverges for some
parameters (found on the independent plant: servo dynamics fitted on top of friction gave
NaN residuals and crashed the whole diagnosis)."""

import numpy as np

from core.gap.roundtrip import NONFINITE_RESIDUAL, fit_ls


def test_a_region_of_nan_residuals_is_avoided_not_a_crash():
    x = np.linspace(0, 1, 50)
    y = 3.0 * x

    def res(th):
        if th[0] > 5.0:  # "the simulation diverged" here
            return np.full(x.size, np.nan)
        return th[0] * x - y

    r = fit_ls(res, [np.array([4.9]), np.array([8.0])], np.array([0.0]), np.array([10.0]), n_starts=2)
    assert abs(r.theta[0] - 3.0) < 1e-6 and np.isfinite(r.rss)


def test_every_start_diverging_returns_the_start_unfitted():
    def res(th):
        return np.full(10, np.inf)

    r = fit_ls(res, [np.array([1.0, 2.0])], np.array([0.0, 0.0]), np.array([5.0, 5.0]))
    assert np.allclose(r.theta, [1.0, 2.0]) and r.rss == 10 * NONFINITE_RESIDUAL**2


def test_a_diverged_test_residual_is_bounded_and_said():
    from core.gap.diagnose import bounded_residual

    notes: list[str] = []
    r = bounded_residual(np.array([1.5, np.inf, -1e70, np.nan, -2.0]), "test contour c.csv", notes)
    assert r.tolist() == [1.5, NONFINITE_RESIDUAL, -NONFINITE_RESIDUAL, NONFINITE_RESIDUAL, -2.0]
    assert notes == [f"the model's simulation diverged on test contour c.csv (3 samples counted as {NONFINITE_RESIDUAL:g} µm)"]
    ok = np.array([0.3, -0.2])
    assert bounded_residual(ok, "x", notes) is ok and len(notes) == 1


def test_a_fit_stopped_by_its_evaluation_cap_says_so():
    x = np.linspace(0.0, 1.0, 200)
    y = np.exp(-3.0 * x) * np.sin(9.0 * x)

    def res(th):
        return np.exp(-th[0] * x) * np.sin(th[1] * x) - y

    start, lo, hi = [np.array([0.5, 5.0])], np.array([0.0, 0.0]), np.array([10.0, 20.0])
    assert fit_ls(res, start, lo, hi, max_nfev=2).capped
    done = fit_ls(res, start, lo, hi, max_nfev=200)
    assert not done.capped and np.allclose(done.theta, [3.0, 9.0], atol=1e-4)
