"""A backlash that changes with temperature and along the travel, on train strokes that
each run at their own temperature over their own stretch of it (as a shop characterises
an axis over a day): either family alone takes the other's part, the pair is what
explains the cold test stroke, and a stretch between strokes that no train sample
crosses leaves the profile's parameters identifiable."""

import numpy as np
import pytest

from core.dataset import Dataset, MachineSpec
from core.gap import GapSettings, diagnose
from core.gap.families.backlash_profile import profile_knots, seen_knots
from core.sim import AxisModel, BacklashProfile, Effects, Encoders, Thermal, round_trip, simulate

# (start mm, end mm, feed mm/min, temperature °C): three train strokes over the travel,
# none crossing 175-290 mm, and a cold test stroke over most of it
STROKES = ((40.0, 175.0, 600.0, 17.2), (290.0, 510.0, 980.0, 24.1), (400.0, 760.0, 1600.0, 20.3),
           (60.0, 600.0, 2400.0, 9.0))  # fmt: skip
WIDTH_UM = 60.0


def temperature_and_wear(seed: int, backlash_um_per_k: float, width_um: float = WIDTH_UM, bump: float = 0.5,
                         temperatures_c: tuple[float, ...] | None = None) -> Dataset:
    """One axis: a wear bump of +``bump`` over 270-570 mm of a ``width_um`` backlash
    changing by ``backlash_um_per_k`` (with the lead growing 8 ppm/K); the strokes'
    temperatures are STROKES' unless given."""
    pos = np.linspace(0.0, 800.0, 17)
    shape = np.clip(1.0 - np.abs(pos - 420.0) / 150.0, 0.0, None)
    fx = Effects(thermal=Thermal(backlash_um_per_k=backlash_um_per_k, lead_growth_ppm_per_k=8.0),
                 backlash_profile=BacklashProfile(tuple(pos), tuple(width_um * (1.0 + bump * shape))))  # fmt: skip
    m = AxisModel(name="x", transmission_mm_per_rev=8.0, screw_lead_mm=16.0, position_gain_per_s=20.0,
                  backlash_um=width_um, effects=fx, encoders=Encoders(table_noise_um=0.3, motor_noise_um=0.3))  # fmt: skip
    temps = temperatures_c or tuple(s[3] for s in STROKES)
    rng = np.random.default_rng(seed)
    runs = []
    for i, ((lo, hi, feed, _), temp) in enumerate(zip(STROKES, temps)):
        prog = round_trip(lo, hi, feed, 600.0, 0.5, axis="x")
        tr = simulate({"x": m}, prog, temperature_c=temp, rate_hz=250.0, rng=rng)
        runs.append(tr.to_run(f"rt_{i}.csv", split="test" if i == len(STROKES) - 1 else "train"))
    return Dataset(MachineSpec("m", {"x": m.to_axis_spec((0.0, 800.0))}), tuple(runs))


def test_a_knot_no_train_stroke_reaches_is_left_out():
    knots = profile_knots(40.0, 760.0)  # 40 mm apart
    strokes = [np.linspace(lo, hi, 50) for lo, hi, _, _ in STROKES[:3]]
    kept = seen_knots(knots, strokes)
    assert kept[0] == 40.0 and kept[-1] == 760.0
    assert 240.0 not in kept  # 200-280 mm: between the first two strokes
    assert {200.0, 280.0} <= set(kept)  # each has samples between its neighbours
    assert kept.size == knots.size - 1
    assert np.array_equal(seen_knots(knots, [np.linspace(40.0, 760.0, 500)]), knots)


@pytest.mark.parametrize("backlash_um_per_k", (2.5, -2.5))
def test_backlash_by_temperature_and_along_the_travel_is_named_as_both(backlash_um_per_k):
    rep = diagnose(temperature_and_wear(43, backlash_um_per_k), GapSettings(keep_curves=False), workers=1)
    assert set(rep.effects) == {"thermal", "backlash_profile"}, rep.text()
    assert rep.gap_after_um <= 0.3 * rep.gap_before_um, rep.text()
    pair = next(c for c in rep.pairs if set(c.effect.split("+")) == set(rep.effects))
    assert pair.identifiable, rep.text()
    assert all(isinstance(v, float) for v in pair.params.values()), pair.params  # every knot pinned down
    assert pair.params["x.backlash_um_per_k"] == pytest.approx(backlash_um_per_k, abs=1.0), pair.params
    assert pair.params["x.lead_growth_ppm_per_k"] == pytest.approx(8.0, abs=0.5), pair.params


def test_a_family_that_makes_the_gap_worse_alone_is_named_in_its_pair():
    """A wide backlash (146 µm, +60 % over the bump) falling 3.9 µm/K, a warm test stroke:
    thermal alone reads the bump as temperature and makes the held-out gap worse ("not
    fitted"); on top of the profile it explains the gap."""
    ds = temperature_and_wear(43, -3.9, width_um=146.0, bump=0.6, temperatures_c=(20.8, 24.0, 16.7, 29.2))
    rep = diagnose(ds, GapSettings(keep_curves=False), workers=1)
    thermal = next(c for c in rep.candidates if c.effect == "thermal")
    assert not thermal.fitted and thermal.gap_after_um > rep.gap_before_um, rep.text()
    assert set(rep.effects) == {"thermal", "backlash_profile"}, rep.text()
    assert rep.gap_after_um <= 0.3 * rep.gap_before_um, rep.text()
    pair = next(c for c in rep.pairs if set(c.effect.split("+")) == set(rep.effects))
    assert pair.params["x.backlash_um_per_k"] == pytest.approx(-3.9, abs=1.0), pair.params
