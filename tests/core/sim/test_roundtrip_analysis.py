"""The criteria of core.criteria recover what the simulator was configured with."""

import numpy as np
import pytest

from core.criteria import analyze_round_trip
from core.sim import AxisModel, BacklashProfile, Effects, Encoders, Thermal, round_trip, simulate


def test_backlash_profile_and_its_thermal_shift_are_recovered_along_the_travel():
    prof = BacklashProfile(positions_mm=(0.0, 150.0, 300.0), widths_um=(80.0, 140.0, 100.0))
    axis = AxisModel(
        backlash_um=0.0,
        effects=Effects(backlash_profile=prof, thermal=Thermal(backlash_um_per_k=2.5)),
        encoders=Encoders(table_resolution_um=0.05, table_noise_um=0.1),
    )
    tr = simulate({"y": axis}, round_trip(-5.0, 305.0, 1500.0), temperature_c=24.0, rng=np.random.default_rng(1))
    res = analyze_round_trip(tr.time_s, tr.motor_rev["y"], tr.table_mm["y"], axis.to_axis_spec((0.0, 300.0)))
    pos = res.backlash.position_mm
    expected = np.interp(pos, prof.positions_mm, prof.widths_um) + 2.5 * 4.0
    away_from_kink = np.abs(pos - 150.0) > 3.0  # the smoothing rounds the profile's corner
    assert res.backlash.backlash_um[away_from_kink] == pytest.approx(expected[away_from_kink], abs=0.5)
    assert res.backlash_mean_um == pytest.approx(expected.mean(), abs=0.5)
