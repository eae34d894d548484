"""A stored history wears: the backlash grows with the utility day. The nominal model of
runs that carry their utility days takes that wear (a rate fitted on the train runs), so
wear alone is no other effect; without the days the same runs leave a gap far above the
noise floor."""

from dataclasses import replace

import numpy as np

from core.dataset import Dataset, MachineSpec, Run
from core.gap import GapSettings, diagnose
from core.gap.data import MAX_FITTED_ROUND_TRIPS, prepare_runs, thin_train
from core.sim import AxisModel, Encoders, round_trip, simulate

ENC = Encoders(table_noise_um=0.2, motor_noise_um=0.2)
WEAR_UM_PER_DAY = 1.5
# (utility day, feed mm/min, stroke start mm): four train runs over 30 days, the newest held out
HISTORY = ((0.0, 800.0, 10.0), (10.0, 1200.0, 40.0), (20.0, 1000.0, 70.0), (30.0, 1400.0, 20.0), (45.0, 1100.0, 50.0))


def _history(rng) -> Dataset:
    runs = []
    for i, (day, feed, start) in enumerate(HISTORY):
        axis = AxisModel(name="y", transmission_mm_per_rev=6.857, backlash_um=60.0 + WEAR_UM_PER_DAY * day,
                         encoders=ENC)  # fmt: skip
        tr = simulate({"y": axis}, round_trip(start, start + 100.0, feed, 600.0, 0.5, axis="y"), temperature_c=20.0,
                      rate_hz=500.0, rng=rng)  # fmt: skip
        runs.append(tr.to_run(f"rt_{i}.csv", split="test" if i == len(HISTORY) - 1 else "train", utility_day=day))
    return Dataset(MachineSpec("worn", {"y": axis.to_axis_spec((0.0, 200.0))}), tuple(runs))


def test_a_history_of_pure_wear_is_none_and_its_rate_is_measured():
    ds = _history(np.random.default_rng(5))
    rep = diagnose(ds, GapSettings(keep_curves=False))
    assert rep.effect == "none", rep.text()
    assert rep.gap_before_um <= 2.0 * rep.noise_floor_um, rep.text()
    rate, ref_day = rep.nominal_wear["y"]
    assert abs(rate - WEAR_UM_PER_DAY) <= 0.1 * WEAR_UM_PER_DAY and ref_day == 30.0, rep.nominal_wear
    # the nominal backlash is the newest train run's: 60 + 1.5 x 30 µm
    assert abs(rep.nominal_backlash_um["y"] - 105.0) <= 2.0, rep.nominal_backlash_um
    assert "growing 1.5 µm per utility day" in rep.text() or "growing 1.49" in rep.text() or "growing 1.51" in rep.text()
    assert rep.to_dict()["nominal_wear"]["y"]["reference_utility_day"] == 30.0


def test_without_its_utility_days_the_same_history_shows_a_gap():
    ds = _history(np.random.default_rng(5))
    blind = Dataset(ds.machine, tuple(Run(replace(r.spec, utility_day=None), r.columns) for r in ds.runs))
    rep = diagnose(blind, GapSettings(keep_curves=False, second_effect=False))
    assert rep.nominal_wear == {} and rep.gap_before_um > 5.0 * rep.noise_floor_um, rep.text()


def _long_history(rng, days) -> Dataset:
    runs = []
    for i, day in enumerate(days):
        axis = AxisModel(name="y", transmission_mm_per_rev=6.857, backlash_um=60.0 + WEAR_UM_PER_DAY * day,
                         encoders=ENC)  # fmt: skip
        tr = simulate({"y": axis}, round_trip(10.0 + 5 * i, 110.0 + 5 * i, 1000.0, 600.0, 0.5, axis="y"),
                      temperature_c=20.0, rate_hz=500.0, rng=rng)  # fmt: skip
        runs.append(tr.to_run(f"rt_{i:02d}.csv", split="test" if i == len(days) - 1 else "train", utility_day=day))
    return Dataset(MachineSpec("worn", {"y": axis.to_axis_spec((0.0, 200.0))}), tuple(runs))


def test_thinning_keeps_the_first_and_newest_train_runs_evenly_and_marks_the_rest():
    ds = _long_history(np.random.default_rng(1), [3.0 * i for i in range(12)])
    rts, _ = prepare_runs(ds)
    thinned, said = thin_train(rts, max_per_axis=6)
    fitted = [r.file for r in thinned if r.split == "train" and r.fitted]
    assert fitted == ["rt_00.csv", "rt_02.csv", "rt_04.csv", "rt_06.csv", "rt_08.csv", "rt_10.csv"]
    assert [r.file for r in thinned if not r.fitted] == ["rt_01.csv", "rt_03.csv", "rt_05.csv", "rt_07.csv",
                                                         "rt_09.csv"]
    assert all(r.fitted for r in thinned if r.split == "test")
    assert "6 of axis y's 11 train round trips" in said and "rt_09.csv" in said
    unchanged, none_said = thin_train(rts, max_per_axis=11)
    assert all(r.fitted for r in unchanged) and none_said == ""


def test_a_long_history_is_fitted_on_six_train_runs_and_still_measures_its_wear():
    ds = _long_history(np.random.default_rng(2), [3.0 * i for i in range(12)])
    rep = diagnose(ds, GapSettings(keep_curves=False))
    split = rep.to_dict()["split"]
    assert len(split["train"]) == 11 and len(split["fitted"]) == MAX_FITTED_ROUND_TRIPS == 6, split
    assert split["fitted"][0] == "rt_00.csv" and split["fitted"][-1] == "rt_10.csv", split
    assert "left out of the fits" in split["how"], split["how"]
    assert rep.effect == "none", rep.text()
    rate, ref_day = rep.nominal_wear["y"]
    assert abs(rate - WEAR_UM_PER_DAY) <= 0.1 * WEAR_UM_PER_DAY and ref_day == 30.0, rep.nominal_wear
