"""The rattle observation (core.gap.where.rattles): a table that stick-slips or hunts
against the nut through a stroke is found, with its frequency and size; reversals, noise
and the other effects' slow residuals are not taken for one."""


import numpy as np
import pytest

from core.gap.data import RoundTrip
from core.gap.play import play
from core.gap.where import RATTLE_MIN_UM, rattle_sentence, rattles, stick_slips

RATE_HZ = 1000.0


def _stroke(rattle_um=0.0, freq_hz=50.0, noise_um=0.3, ripple_um=0.0, jitter_um=0.0, seed=0):
    """A 0 -> 200 -> 0 mm round trip at 1200 mm/min (20 mm/s) through a 60 µm backlash;
    ``rattle_um`` of a ``freq_hz`` sine on the table while moving, ``ripple_um`` of a
    10 mm period along the travel (a cyclic error: slow at this feed), ``jitter_um`` RMS
    of white error while moving (a table latch with a jittering delay: error = speed x
    jitter)."""
    rng = np.random.default_rng(seed)
    t = np.arange(0.0, 22.0, 1.0 / RATE_HZ)
    tri = np.clip(np.minimum(t - 0.5, 20.5 - t), 0.0, 10.0)  # s of travel at 20 mm/s
    u = 20.0 * tri
    x = play(u, np.full(t.size, 0.03), -0.03)
    moving = np.abs(np.gradient(u, t)) > 1.0
    x = x + 1e-3 * (rattle_um * np.sin(2 * np.pi * freq_hz * t) * moving + ripple_um * np.sin(2 * np.pi * u / 10.0))
    x = x + 1e-3 * noise_um * rng.standard_normal(t.size)
    x = x + 1e-3 * jitter_um * rng.standard_normal(t.size) * moving
    return RoundTrip("rt_x_00.csv", "x", "train", t, u, x, 20.0, 1200.0, None, 1, np.arange(t.size))


def test_a_table_rattling_through_its_strokes_is_found_with_its_frequency_and_size():
    (f,) = rattles([_stroke(rattle_um=40.0, freq_hz=60.0)])  # 3 cycles per 50 ms window
    assert f["file"] == "rt_x_00.csv" and f["axis"] == "x" and f["split"] == "train" and f["feed_mm_min"] == 1200.0
    assert f["frequency_hz"] == pytest.approx(60.0, abs=1.0)
    assert f["rms_um"] == pytest.approx(40.0 / np.sqrt(2), rel=0.1)  # a sine's RMS
    assert f["fraction_of_stroke"] > 0.9
    text = rattle_sentence([f])
    assert "rt_x_00.csv" in text and "60 Hz" in text and "1200 mm/min" in text and "out and back)" in text


@pytest.mark.parametrize("kw", [{}, {"noise_um": 1.0}, {"ripple_um": 6.0}, {"rattle_um": 0.5 * RATTLE_MIN_UM},
                                {"jitter_um": 15.0}],
                         ids=["play_and_reversals", "noisy_encoder", "cyclic_error", "small_ringing", "timing_jitter"])
def test_reversals_noise_jitter_and_slow_residuals_are_not_a_rattle(kw):
    assert rattles([_stroke(**kw)]) == []
    assert rattle_sentence([]) == ""


def test_a_rattle_in_one_direction_only_counts_when_it_fills_a_fifth_of_the_stroke():
    s = _stroke()
    out = s.u_mm > 0  # the outward stroke and the way back; rattle on the way back only
    back = np.arange(s.t_s.size) > np.argmax(s.u_mm)
    x = s.x_mm + 1e-3 * 30.0 * np.sin(2 * np.pi * 40.0 * s.t_s) * (back & out)
    (f,) = rattles([RoundTrip(s.file, "x", "test", s.t_s, s.u_mm, x, 20.0, 1200.0, None, 1, s.fit_idx)])
    assert 0.4 < f["fraction_of_stroke"] < 0.6 and f["split"] == "test"
    assert f["frequency_hz"] == pytest.approx(40.0, abs=1.0)
    assert f["both_directions"] is False  # the way back only: one side
    assert "one direction only)" in rattle_sentence([f])


def test_a_rattle_through_both_directions_is_said_to_be_two_sided():
    (f,) = rattles([_stroke(rattle_um=40.0, freq_hz=60.0)])
    assert f["both_directions"] is True
    s = _stroke()
    back = np.arange(s.t_s.size) > np.argmax(s.u_mm)
    # the outward stroke rattles throughout, the way back over a tenth of it only: under
    # the fifth that makes a direction rattle
    stretch = back & (s.u_mm > 180.0)
    x = s.x_mm + 1e-3 * 30.0 * np.sin(2 * np.pi * 40.0 * s.t_s) * ((~back & (s.u_mm > 0)) | stretch)
    (f,) = rattles([RoundTrip(s.file, "x", "test", s.t_s, s.u_mm, x, 20.0, 1200.0, None, 1, s.fit_idx)])
    assert f["both_directions"] is False and 0.5 < f["fraction_of_stroke"] < 0.65


@pytest.mark.parametrize(("sides", "expected"), [((True, True), True), ((True, False), False), ((), False)])
def test_stick_slip_is_every_rattling_round_trip_rattling_out_and_back(sides, expected):
    assert stick_slips([{"both_directions": b} for b in sides]) is expected
