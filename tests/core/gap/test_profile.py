"""The backlash-profile candidate resolves narrow wear bumps: knots at most 40 mm apart
over the travel the train round trips cross (seven knots, travel / 6 apart, left most of
such a gap: the independent plant's several wear bumps)."""

import numpy as np
import pytest

from core.dataset import Dataset, MachineSpec
from core.gap import GapSettings, diagnose
from core.gap.candidates import PROFILE_KNOT_SPACING_MM, PROFILE_MAX_KNOTS, profile_knots
from core.gap.families.backlash_profile import knot_names, sim_piece
from core.sim import AxisModel, BacklashProfile, Effects, Encoders, circle, round_trip, simulate


@pytest.mark.parametrize("lo, hi, n", [(0.0, 100.0, 7), (40.0, 760.0, 19), (0.0, 2000.0, PROFILE_MAX_KNOTS)])
def test_knots_are_at_most_the_spacing_apart_within_their_bounds(lo, hi, n):
    k = profile_knots(lo, hi)
    assert k.size == n and k[0] == lo and k[-1] == hi
    if n < PROFILE_MAX_KNOTS:
        assert np.max(np.diff(k)) <= PROFILE_KNOT_SPACING_MM + 1e-9


def test_knots_closer_than_a_millimetre_keep_a_parameter_each():
    """Whole millimetres name the knots of a travel of 6 mm and more; closer knots (a 4 mm
    stroke: 0.67 mm apart) take the decimals that tell them apart, so each stays a
    parameter and the profile simulated on contours has a width per knot."""
    assert knot_names(profile_knots(0.0, 240.0))[:2] == ("backlash_change_at_40mm_um", "backlash_change_at_80mm_um")
    knots = profile_knots(10.0, 14.0)
    names = knot_names(knots)
    assert len(set(names)) == knots.size - 1 == 6, names
    piece, share = sim_piece({n: float(i) for i, n in enumerate(names, 1)}, {"positions_mm": knots.tolist()}, None, 50.0)
    assert piece.widths_um == (50.0, 51.0, 52.0, 53.0, 54.0, 55.0, 56.0) and share == 0.0


def test_round_trips_of_a_few_millimetres_with_circles_are_diagnosed():
    """A backlash that changes within a 4 mm stroke: the profile's fit, taken on the round
    trips, simulated on the circles on the knots of that stroke."""
    wear = Effects(backlash_profile=BacklashProfile((10.0, 12.0, 14.0), (50.0, 90.0, 55.0)))
    axes = {a: AxisModel(name=a, transmission_mm_per_rev=6.857, backlash_um=60.0, effects=wear,
                         encoders=Encoders(table_noise_um=0.2, motor_noise_um=0.2)) for a in "xy"}  # fmt: skip
    rng = np.random.default_rng(3)
    runs = []
    for i, feed in enumerate((1200.0, 2000.0, 3000.0)):
        tr = simulate({"y": axes["y"]}, round_trip(10.0, 14.0, feed, 1500.0, 0.1, axis="y"), rate_hz=500.0, rng=rng)
        runs.append(tr.to_run(f"rt_{i}.csv", split="test" if i == 2 else "train"))
    for i, feed in enumerate((1200.0, 2000.0)):
        tr = simulate(axes, circle(3.0, (100.0, 100.0), feed, ("ccw", "cw")[i]), rate_hz=500.0, rng=rng)
        runs.append(tr.to_run(f"c_{i}.csv", split="test" if i == 1 else "train"))
    ds = Dataset(MachineSpec("m", {a: m.to_axis_spec((0.0, 200.0)) for a, m in axes.items()}), tuple(runs))
    rep = diagnose(ds, GapSettings(keep_curves=False, second_effect=False), workers=1)
    prof = next(c for c in rep.candidates if c.effect == "backlash_profile")
    assert len([k for k in prof.params if k.startswith("y.backlash_change_at_")]) == 6, prof.params


def test_three_narrow_wear_bumps_are_named_and_located():
    """Three Gaussian bumps (sigma 20-30 mm, not the candidate's piecewise-linear form) on
    an 800 mm axis; the train strokes cross the whole travel, the test stroke part of it."""
    pos = np.linspace(0.0, 800.0, 161)  # the truth on a 5 mm grid
    bumps = ((180.0, 20.0, 0.5), (430.0, 30.0, 0.35), (620.0, 25.0, 0.45))
    rel = sum(a * np.exp(-0.5 * ((pos - c) / w) ** 2) for c, w, a in bumps)
    b_um = 50.0
    fx = Effects(backlash_profile=BacklashProfile(tuple(pos), tuple(b_um * (1 + rel))))
    enc = Encoders(table_noise_um=0.3, motor_noise_um=0.3)
    m = AxisModel(name="x", transmission_mm_per_rev=8.0, screw_lead_mm=16.0, position_gain_per_s=20.0,
                  backlash_um=b_um, encoders=enc, effects=fx)  # fmt: skip
    rng = np.random.default_rng(5)
    strokes = ((20, 780, 3000), (20, 780, 4500), (20, 780, 2100), (100, 700, 3600))  # feeds in mm/min
    runs = []
    for i, (lo, hi, feed) in enumerate(strokes):
        tr = simulate({"x": m}, round_trip(lo, hi, feed, 600.0, 0.3, axis="x"), rate_hz=250.0, rng=rng)
        runs.append(tr.to_run(f"rt_{i}.csv", split="test" if i == 3 else "train"))
    ds = Dataset(MachineSpec("m", {"x": m.to_axis_spec((0.0, 800.0))}), tuple(runs))
    rep = diagnose(ds, workers=1)
    assert rep.effect == "backlash_profile", rep.text()
    assert rep.gap_after_um <= 0.3 * rep.gap_before_um, rep.text()
    prof = rep.candidates[0].params
    at = {float(k.split("_at_")[1].split("mm")[0]): v for k, v in prof.items() if "backlash_change_at_" in k}
    peak = max(at, key=lambda x: at[x] if isinstance(at[x], float) else -1e9)
    assert min(abs(peak - c) for c, _, _ in bumps) <= PROFILE_KNOT_SPACING_MM  # the widest change sits on a bump
