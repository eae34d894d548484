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


def _two_place_residuals(x, y, sims):
    """Residuals of a model that simulates two places and keeps the better one (as a
    chain's start place), recording its choice and holding a held one. The second place
    doubles the residual: never the better one, so the choice never changes."""
    from core.gap.roundtrip import run_choices

    def res(th):
        ch = run_choices()
        held = None if ch is None else ch.held.get(0)
        tried = [held] if held is not None else (0, 1)
        best = None
        for i in tried:
            sims.append(i)
            r = (1.0 + i) * (th[0] * x + th[1] - y)
            if best is None or np.sum(r**2) < np.sum(best[1] ** 2):
                best = (i, r)
        if ch is not None and held is None:
            ch.made[0] = best[0]
        return best[1]

    return res


def test_a_jacobian_with_the_choices_held_is_least_squares_own_at_one_simulation_a_column():
    x = np.linspace(0.0, 1.0, 40)
    y = 2.0 * x + 0.3 + 0.01 * np.sin(17 * x)
    free_sims: list[int] = []
    held_sims: list[int] = []
    lo, hi = np.array([-10.0, -10.0]), np.array([10.0, 10.0])
    free = fit_ls(_two_place_residuals(x, y, free_sims), [np.array([1.0, 0.0])], lo, hi)
    held = fit_ls(_two_place_residuals(x, y, held_sims), [np.array([1.0, 0.0])], lo, hi, hold_choices=True)
    # the place never changes near the path: the fit is the one least_squares makes alone
    assert np.array_equal(free.theta, held.theta) and np.array_equal(free.jac, held.jac)
    assert abs(held.theta[0] - 2.0) < 0.05
    # a free evaluation simulates both places; a Jacobian column only the one chosen
    assert len(free_sims) % 2 == 0 and held_sims.count(1) < free_sims.count(1)
    n_eval = free_sims.count(1)  # evaluations of either kind in the free fit (each tries place 1)
    n_cols = n_eval - held_sims.count(1)  # those that became held columns
    assert n_cols > 0 and len(held_sims) == 2 * (n_eval - n_cols) + n_cols


def test_run_choices_reach_the_threads_that_simulate_the_runs(monkeypatch):
    import core.gap.roundtrip as rt
    from core.gap.roundtrip import RunChoices, choosing, map_runs, run_choices

    monkeypatch.setattr(rt, "RUN_THREADS", 4)  # the pool, on a machine of any size
    runs = [object() for _ in range(4)]

    def sim(r):
        ch = run_choices()
        ch.made[id(r)] = ch.held.get(id(r), 0) + 1
        return np.zeros(1)

    with choosing(RunChoices(held={id(runs[2]): 5})) as ch:
        map_runs(sim, runs)
    assert ch.made == {id(runs[0]): 1, id(runs[1]): 1, id(runs[2]): 6, id(runs[3]): 1}
    assert run_choices() is None
