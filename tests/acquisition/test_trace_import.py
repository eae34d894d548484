"""acquisition.trace_import.steady_feed_mm_min: the feed a round trip ran at, from its
positions, with encoder noise; refused, naming the option, where there is none to read."""

import numpy as np
import pytest

from acquisition.trace_import import TraceImportError, steady_feed_mm_min
from core.sim import round_trip


def _positions(feed_mm_min, rate_hz=1000.0, noise_um=0.3, seed=1):
    prog = round_trip(10.0, 210.0, feed_mm_min, 500.0, 0.2, axis="x")
    t = np.arange(0.0, prog.duration_s, 1.0 / rate_hz)
    x = prog.command_mm(t)["x"] + np.random.default_rng(seed).normal(0.0, noise_um * 1e-3, t.size)
    return t, x


@pytest.mark.parametrize("feed", [600.0, 2400.0, 6000.0])
def test_the_feed_is_the_strokes_steady_speed(feed):
    t, x = _positions(feed)
    got = steady_feed_mm_min(t, x)
    assert got.feed_mm_min == pytest.approx(feed, rel=1e-3)
    assert all(v == pytest.approx(feed, rel=2e-3) for v in got.stroke_speeds_mm_min)


def test_a_trace_of_one_stroke_or_no_steady_speed_is_refused_naming_the_option():
    t, x = _positions(2400.0)
    with pytest.raises(TraceImportError, match="no negative stroke to read the feed from .*--feed-mm-min"):
        steady_feed_mm_min(t[: t.size // 2], x[: t.size // 2])
    ramp = 0.5 * 5000.0 * t[:200] ** 2  # out and back, accelerating all the way: no constant speed
    with pytest.raises(TraceImportError, match="stroke has no stretch of constant speed of 0.1 s .*--feed-mm-min"):
        steady_feed_mm_min(t[:400], np.concatenate([ramp, ramp[::-1]]))
