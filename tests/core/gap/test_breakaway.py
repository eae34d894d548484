"""The break-away observation (core.gap.where.breakaways): a table that, while the command
stands still, stays put and then jumps (static friction giving way to a chain the position
loop winds up) is found; a table that follows a creeping motor, settles after the stop,
jumps once only or is only noisy is not. What the decision does with it: tests/core/gap/test_select.py."""

from dataclasses import replace

import numpy as np
import pytest

from core.gap.data import RoundTrip
from core.gap.where import BREAKAWAY_MIN_UM, BREAKAWAY_SETTLE_S, breakaway_sentence, breakaways

RATE_HZ = 1000.0


def _stroke(jumps=((0.5, 30.0), (0.5, -30.0)), creep_mm_s=0.0, noise_um=0.3, command=True, seed=0, file="rt_x_00.csv"):
    """0 -> 100 -> 0 mm at 20 mm/s: 0.5 s at rest, 5 s out, a 2 s dwell, 5 s back, a 2 s rest.
    The table follows the motor on a 40 µm backlash; at rest it crawls with the motor at
    ``creep_mm_s`` (smoothly) and, at ``(s after the command stopped, µm)`` of ``jumps``
    (the first in the dwell, the second in the final rest), jumps by that much over 5 ms."""
    rng = np.random.default_rng(seed)
    t = np.arange(0.0, 14.5, 1.0 / RATE_HZ)
    c = np.interp(t, [0.5, 5.5, 7.5, 12.5], [0.0, 100.0, 100.0, 0.0])
    stops = (5.5, 12.5)
    u = c.copy()
    x = c + 0.02 * (np.clip((t - 7.5) / 0.05, 0.0, 2.0) - 1.0)  # half the gap behind the nut, crossing it on the way back
    for stop in stops:
        after = t > stop
        u = u + creep_mm_s * (t - stop) * after * (t < stop + 2.0)
        x = x + creep_mm_s * (t - stop) * after * (t < stop + 2.0)
    for (dt, um), stop in zip(jumps, stops):
        t0 = stop + dt
        x = x + 1e-3 * um * np.clip((t - t0) / 0.005, 0.0, 1.0)
    x = x + 1e-3 * noise_um * rng.standard_normal(t.size)
    return RoundTrip(file, "x", "train", t, u, x, 20.0, 1200.0, None, 1, np.arange(t.size), c if command else None)


def test_a_table_that_holds_then_jumps_at_rest_is_found_with_its_jumps():
    (f,) = breakaways([_stroke()])
    assert f["file"] == "rt_x_00.csv" and f["axis"] == "x" and f["split"] == "train" and f["feed_mm_min"] == 1200.0
    assert f["events"] == 2 and f["jump_um"] == pytest.approx(30.0, abs=2.0)
    assert f["threshold_um"] == pytest.approx(BREAKAWAY_MIN_UM)  # 8x the noise of the 10 ms steps is less
    text = breakaway_sentence([f])
    assert "rt_x_00.csv" in text and "breaks away at rest" in text and "2 time(s)" in text


def test_one_jump_per_round_trip_counts_when_two_round_trips_have_one():
    a = _stroke(jumps=((0.5, 30.0), (0.5, 0.0)))
    b = _stroke(jumps=((0.8, -25.0), (0.5, 0.0)), seed=1, file="rt_x_01.csv")
    assert breakaways([a]) == []  # one event alone: a machine's friction repeats
    found = breakaways([a, b])
    assert [f["file"] for f in found] == ["rt_x_00.csv", "rt_x_01.csv"] and [f["events"] for f in found] == [1, 1]


@pytest.mark.parametrize("kw", [
    {"jumps": ((0.5, 0.0), (0.5, 0.0))},                              # the table rests
    {"jumps": ((0.5, 0.0), (0.5, 0.0)), "creep_mm_s": 1.0},            # it follows a creeping motor
    {"jumps": ((0.5, 0.0), (0.5, 0.0)), "noise_um": 1.0},              # a noisier encoder
    {"jumps": ((0.5, 0.6 * BREAKAWAY_MIN_UM), (0.5, -0.6 * BREAKAWAY_MIN_UM))},  # too small
    {"jumps": ((0.5 * BREAKAWAY_SETTLE_S, 30.0), (0.5 * BREAKAWAY_SETTLE_S, -30.0))},  # the stop's settling
    {"command": False},                                                  # still stretches unknown
], ids=["at_rest", "creeping_motor", "noisy_encoder", "small_jumps", "settling", "no_command"])
def test_rest_creep_noise_settling_and_small_steps_are_not_a_breakaway(kw):
    assert breakaways([_stroke(**kw)]) == []
    assert breakaway_sentence([]) == ""


def test_a_jump_without_a_hold_before_it_is_not_a_breakaway():
    s = _stroke(jumps=((0.5, 0.0), (0.5, 0.0)))
    wobble = 1e-3 * 20.0 * np.sin(2 * np.pi * 30.0 * s.t_s) * (s.command_mm >= 100.0)  # a ring through the dwell
    x = s.x_mm + wobble
    assert breakaways([replace(s, x_mm=x)]) == []
