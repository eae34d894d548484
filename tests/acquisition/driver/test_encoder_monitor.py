"""EncoderMonitor: jumping and stuck encoders, across block boundaries."""

from __future__ import annotations

import numpy as np
import pytest

from acquisition.driver.encoder_monitor import EncoderMonitor
from acquisition.errors import EncoderFaultError
from acquisition.types import RoundTripProgram

K_A = 10.0  # mm per motor revolution
RATE_HZ = 1000.0
PROGRAM = RoundTripProgram(0.0, 50.0, 600.0)  # 10 mm/s: 0.01 mm per sample


def _monitor(**kw):
    kw.setdefault("jump_margin_mm", 0.05)
    kw.setdefault("stuck_travel_mm", 1.0)
    return EncoderMonitor(PROGRAM, K_A, RATE_HZ, **kw)


def _ramp(n, start_k=0, x0=0.0, step_mm=0.01):
    c = np.arange(start_k, start_k + n)
    table = x0 + step_mm * np.arange(n)
    return c, table / K_A, table


def test_a_clean_motion_passes_in_any_block_split():
    c, m, t = _ramp(3000)
    mon = _monitor()
    for lo in range(0, 3000, 250):
        mon.check(c[lo:lo + 250], m[lo:lo + 250], t[lo:lo + 250])


def test_a_jump_is_reported_with_the_samples_it_lies_between():
    c, m, t = _ramp(500)
    t[300:] += 0.5
    with pytest.raises(EncoderFaultError, match=r"linear \(table\) encoder jumped by 0\.5\d* mm between samples 299 and 300") as e:
        _monitor().check(c, m, t)
    assert e.value.encoder == "table"


def test_a_jump_across_a_block_boundary_is_caught():
    c, m, t = _ramp(400)
    m[200:] += 0.1  # motor: 1 mm at K_A = 10
    mon = _monitor()
    mon.check(c[:200], m[:200], t[:200])
    with pytest.raises(EncoderFaultError, match="rotary") as e:
        mon.check(c[200:], m[200:], t[200:])
    assert e.value.encoder == "motor"


def test_a_counter_gap_allows_the_longer_step():
    c, m, t = _ramp(100)
    c2 = np.concatenate([c[:50], c[50:] + 20])  # 20 samples lost: 0.2 mm more travel is plausible
    t2 = np.concatenate([t[:50], t[50:] + 0.2])
    _monitor(jump_margin_mm=0.0).check(c2, t2 / K_A, t2)


def test_skew_widens_the_allowed_step():
    c, m, t = _ramp(100)
    t[50:] += 0.08
    with pytest.raises(EncoderFaultError):
        _monitor(jump_margin_mm=0.0).check(c, m, t)
    _monitor(jump_margin_mm=0.0).check(c, m, t, skew_s=0.005)  # 2 x 10 mm/s x 2 x 5 ms = 0.2 mm


def test_a_stuck_table_is_reported_once_the_motor_has_travelled_beyond_the_limit():
    c, m, t = _ramp(300)
    t[100:] = t[100]  # table frozen while the motor goes on
    mon = _monitor(stuck_travel_mm=1.0)
    mon.check(c[:150], m[:150], t[:150])  # 0.5 mm of motor travel since: not yet
    with pytest.raises(EncoderFaultError, match=r"linear \(table\) encoder stuck") as e:
        mon.check(c[150:], m[150:], t[150:])
    assert e.value.encoder == "table"


def test_backlash_sized_dead_travel_is_not_stuck():
    # at a reversal the table waits while the motor takes up the backlash (0.12 mm here)
    c, m, t = _ramp(200)
    t[100:112] = t[100]
    t[112:] -= 0.12
    _monitor().check(c, m, t)


def test_an_empty_block_changes_nothing():
    mon = _monitor()
    mon.check(np.zeros(0, dtype=np.int64), np.zeros(0), np.zeros(0))
    c, m, t = _ramp(10)
    mon.check(c, m, t)
