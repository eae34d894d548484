"""The seed paper's TBE figures (../shared/reference/paper-figures.md) and properties of Eqs. 7-11."""

import numpy as np
import pytest
from hypothesis import example, given, settings
from hypothesis import strategies as st

from core.errors import InputError, ModelDomainError
from core.tbe.formulas import circle_backlash_domain_um
from core.tbe import backlash_limit_um, circle_steady_lag_um, tbe_circle_um, tbe_line_um

PAPER = dict(radius_mm=200.0, feed_mm_min=200.0, gain_per_s=10.0)


@pytest.mark.parametrize(
    ("backlash_um", "tbe_um"),
    [(100.0, 24.29), (236.0, 45.00), (239.5, 45.47), (240.1, 45.55)],
)
def test_circle_tbe_matches_paper_figures(backlash_um, tbe_um):
    assert float(tbe_circle_um(backlash_um, **PAPER)) == pytest.approx(tbe_um, abs=0.02)


def test_circle_tbe_small_radius_high_feed_matches_reference():
    # paper-figures.md: R = 25 mm at 3000 mm/min, K = 10, b = 300 µm gives Eq. 8 240.20 µm
    assert float(tbe_circle_um(300.0, 25.0, 3000.0, 10.0)) == pytest.approx(240.20, abs=0.02)


def test_backlash_limit_for_45_um_is_236():
    assert backlash_limit_um(45.0, **{k: PAPER[k] for k in ("feed_mm_min", "gain_per_s")},
                             radius_mm=200.0) == pytest.approx(236.0, abs=0.1)


def test_steady_lag_and_absolute_radial_peaks():
    # The absolute peaks 44.68 / 23.98 µm are the reference's time-domain simulation,
    # which agrees with Eq. 8 within 0.2 %; the simulator's tests hit them exactly.
    lag = circle_steady_lag_um(**PAPER)
    assert lag == pytest.approx(0.28, abs=0.005)
    assert float(tbe_circle_um(236.0, **PAPER)) - lag == pytest.approx(44.68, rel=0.002)
    assert float(tbe_circle_um(100.0, **PAPER)) - lag == pytest.approx(23.98, rel=0.002)


@pytest.mark.parametrize(
    ("b", "feed", "angle", "k", "expected"),
    [(236, 200, 45, 10, 109.67), (100, 1000, 30, 10, 44.33), (50, 2000, 60, 25, 38.21)],
)
def test_line_tbe_matches_paper_figures(b, feed, angle, k, expected):
    assert float(tbe_line_um(b, angle, feed, k)) == pytest.approx(expected, abs=0.02)


def test_vectorised_over_backlash():
    b = np.array([100.0, 236.0, 240.1])
    out = tbe_circle_um(b, **PAPER)
    assert out.shape == (3,)
    assert out == pytest.approx([float(tbe_circle_um(x, **PAPER)) for x in b])
    assert tbe_line_um(b, 45, 200, 10).shape == (3,)


def test_zero_backlash_gives_zero_tbe():
    assert float(tbe_circle_um(0.0, **PAPER)) == 0.0
    assert float(tbe_line_um(0.0, 45, 200, 10)) == 0.0


def test_large_backlash_is_numerically_stable():
    # Δ is hugely negative here; the naive (Δ + √(Δ²-2916)) loses every digit.
    b = np.geomspace(1e-3, 5000, 200)
    tbe = tbe_circle_um(b, 50.0, 3000.0, 30.0)
    assert np.all(np.isfinite(tbe))
    assert np.all(np.diff(tbe) > 0)


circle_cases = st.tuples(
    st.floats(5.0, 500.0),  # radius_mm
    st.floats(50.0, 5000.0),  # feed_mm_min
    st.floats(5.0, 50.0),  # gain_per_s
)


@settings(max_examples=60, deadline=None)
@given(circle_cases, st.floats(1.0, 400.0), st.floats(1.0, 400.0))
def test_circle_tbe_monotone_in_backlash(case, b1, b2):
    r, f, k = case
    lo, hi = sorted((b1, b2))
    if hi - lo < 1e-6:
        return
    assert float(tbe_circle_um(hi, r, f, k)) > float(tbe_circle_um(lo, r, f, k))


@settings(max_examples=60, deadline=None)
@given(st.floats(-80.0, 80.0), st.floats(50.0, 5000.0), st.floats(5.0, 50.0), st.floats(1.0, 400.0), st.floats(1.0, 400.0))
def test_line_tbe_monotone_in_backlash(angle, feed, k, b1, b2):
    lo, hi = sorted((b1, b2))
    if hi - lo < 1e-6 or abs(angle) < 1.0:
        return
    assert float(tbe_line_um(hi, angle, feed, k)) > float(tbe_line_um(lo, angle, feed, k))


def _circle_edge_um(r, f, k):
    """The largest backlash Eq. 8 covers, capped at backlash_limit_um's default search bound."""
    return min(circle_backlash_domain_um(r, f, k), 5000.0)


@settings(max_examples=200, deadline=None)
@given(circle_cases, st.floats(1e-4, 1.0))
@example((5.0, 2226.5, 5.0), 1.0)  # the domain edge itself
@example((500.0, 50.0, 5.0), 1.0)
def test_limit_inverts_circle_tbe_over_whole_domain(case, fraction):
    # b is drawn as a fraction of the whole validity domain of Eq. 8, edge included,
    # not from a fixed range that misses the edge on small, fast circles.
    r, f, k = case
    b = fraction * _circle_edge_um(r, f, k)
    tol = float(tbe_circle_um(b, r, f, k))
    got = backlash_limit_um(tol, feed_mm_min=f, gain_per_s=k, radius_mm=r)
    # Eq. 8 is flat in b at the edge (d sin(ωT) = 0 at ωT = π/2): compare in TBE there.
    assert float(tbe_circle_um(got, r, f, k)) == pytest.approx(tol, rel=1e-9, abs=1e-9)
    if fraction < 0.9:
        assert got == pytest.approx(b, rel=1e-6, abs=1e-6)


@settings(max_examples=200, deadline=None)
@given(circle_cases, st.floats(0.01, 1000.0))
@example((5.0, 2226.5, 5.0), 10.0)  # refused with "outside Eq. 8"
def test_limit_answers_every_circle_tolerance(case, tol):
    r, f, k = case
    edge = _circle_edge_um(r, f, k)
    top = float(tbe_circle_um(edge, r, f, k))
    if tol > top:
        with pytest.raises(ModelDomainError, match="met by any backlash"):
            backlash_limit_um(tol, feed_mm_min=f, gain_per_s=k, radius_mm=r)
        return
    got = backlash_limit_um(tol, feed_mm_min=f, gain_per_s=k, radius_mm=r)
    assert 0.0 < got <= edge
    assert float(tbe_circle_um(got, r, f, k)) == pytest.approx(tol, rel=1e-9, abs=1e-9)


def test_limit_on_the_circle_where_the_tbe_peaks_near_the_tolerance():
    got = backlash_limit_um(10.0, feed_mm_min=2226.5, gain_per_s=5.0, radius_mm=5.0)
    assert float(tbe_circle_um(got, 5.0, 2226.5, 5.0)) == pytest.approx(10.0, rel=1e-9)
    assert got == pytest.approx(10.233, abs=0.001)


@settings(max_examples=60, deadline=None)
@given(st.floats(5.0, 85.0), st.floats(50.0, 5000.0), st.floats(5.0, 50.0), st.floats(5.0, 400.0))
def test_limit_inverts_line_tbe(angle, f, k, b):
    tol = float(tbe_line_um(b, angle, f, k))
    assert backlash_limit_um(tol, feed_mm_min=f, gain_per_s=k, angle_deg=angle) == pytest.approx(b, rel=1e-6, abs=1e-6)


def test_limit_errors_are_typed_and_say_why():
    with pytest.raises(ModelDomainError, match="met by any backlash"):
        backlash_limit_um(1e6, feed_mm_min=200, gain_per_s=10, radius_mm=200)
    with pytest.raises(InputError, match="tolerance_um"):
        backlash_limit_um(0.0, feed_mm_min=200, gain_per_s=10, radius_mm=200)
    with pytest.raises(InputError, match="feed_mm_min"):
        backlash_limit_um(45.0, feed_mm_min=-1, gain_per_s=10, radius_mm=200)
    with pytest.raises(InputError, match="exactly one"):
        backlash_limit_um(45.0, feed_mm_min=200, gain_per_s=10)


@pytest.mark.parametrize(
    "call",
    [
        lambda: tbe_circle_um(np.nan, 200, 200, 10),
        lambda: tbe_circle_um(-1.0, 200, 200, 10),
        lambda: tbe_circle_um(100, 0.0, 200, 10),
        lambda: tbe_circle_um(100, 200, 0.0, 10),
        lambda: tbe_circle_um(100, 200, 200, float("inf")),
        lambda: tbe_line_um(100, 90.0, 200, 10),
        lambda: tbe_line_um(100, 45.0, -200, 10),
    ],
)
def test_bad_inputs_raise_input_error(call):
    with pytest.raises(InputError):
        call()


def test_circle_outside_model_domain_is_reported():
    # a backlash so large that the axis would not reverse within the quadrant
    with pytest.raises(ModelDomainError, match="quarter turn"):
        tbe_circle_um(5e9, 10.0, 10000.0, 5.0)
