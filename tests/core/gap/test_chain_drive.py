"""The chain kernels are driven by the motor record as sampled.

With the position loop closed on the table scale, a chain that hunts moves the motor at
the chain's frequency (tens to a few hundred hertz): the drive of the round-trip chain
models must carry that band, or a model does not fall into the cycle the machine runs.
"""

import numpy as np
import pytest

from core.gap.candidates import drive_u
from core.gap.data import RoundTrip


def _record(freq_hz: float, amp_um: float, rate_hz: float = 1000.0) -> RoundTrip:
    t = np.arange(int(2.0 * rate_hz)) / rate_hz
    u = 10.0 * t + 1e-3 * amp_um * np.sin(2 * np.pi * freq_hz * t)  # a 10 mm/s stroke, the motor rattling on it
    return RoundTrip("rt.csv", "x", "train", t, u, u.copy(), 20.0, 600.0, 500.0, 1, np.arange(t.size))


@pytest.mark.parametrize("freq_hz", [25.0, 50.0, 100.0])
def test_the_drive_keeps_the_motor_rattle_at_a_chain_frequency(freq_hz):
    run = _record(freq_hz, 3.0)
    u, v = drive_u(run, {})
    inner = slice(100, -100)
    np.testing.assert_array_equal(u, run.u_mm)  # the positions as recorded
    rattle_mm_s = v[inner] - 10.0
    # central differences: sin(w dt) / (w dt) of the velocity's amplitude, 93.5 % at 100 Hz at
    # 1 kHz (an order-2 Savitzky-Golay derivative over 30 ms keeps half of 25 Hz, 5 % of 50 Hz)
    expected = 2 * np.pi * freq_hz * 3e-3 * np.sinc(2 * freq_hz / 1000.0)
    assert np.sqrt(2.0) * np.std(rattle_mm_s) == pytest.approx(expected, rel=0.01)
    assert np.sqrt(2.0) * np.std(rattle_mm_s) > 0.9 * 2 * np.pi * freq_hz * 3e-3


def test_the_drive_is_kept_per_run_in_the_diagnosis_memo():
    run = _record(50.0, 3.0)
    memo: dict = {}
    u, v = drive_u(run, memo)
    u2, v2 = drive_u(run, memo)
    assert u2 is u and v2 is v
