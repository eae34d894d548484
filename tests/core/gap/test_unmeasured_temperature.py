"""A run whose temperature no thermometer read (``temperature_measured: false``, the
reference 20 °C stored in its place) is judged by the measured runs' temperatures: it is
not held out as the most extreme temperature, the thermal family does not read its
stand-in as a temperature step, and the where-analysis leaves it out of its
temperature trend."""

from dataclasses import replace

import numpy as np

from core.dataset import Dataset, MachineSpec
from core.gap import GapSettings, diagnose
from core.gap.data import choose_split, prepare_runs
from core.sim import AxisModel, Effects, Encoders, Thermal, round_trip, simulate

ENC = Encoders(table_noise_um=0.2, motor_noise_um=0.2)
# feed, acceleration, measured temperature (°C) of the round trips; the last one's is not measured
CONDITIONS = ((600.0, 400.0, 24.9), (1000.0, 600.0, 25.1), (1500.0, 800.0, 25.0), (2400.0, 1500.0, 24.95),
              (800.0, 500.0, 25.05))


def _dataset(effects: Effects, split: bool) -> Dataset:
    """Round trips of one axis at 25 ± 0.1 °C; the last run's thermometer was missing."""
    axis = AxisModel(name="y", transmission_mm_per_rev=6.857, backlash_um=60.0, effects=effects, encoders=ENC)
    rng = np.random.default_rng(11)
    runs = []
    for i, (feed, acc, temp) in enumerate(CONDITIONS):
        start = (10.0, 40.0, 70.0, 30.0, 50.0)[i]
        prog = round_trip(start, start + 100.0, feed, acc, 0.5, axis="y")
        tr = simulate({"y": axis}, prog, temperature_c=temp, rate_hz=500.0, rng=rng)
        run = tr.to_run(f"rt_{i}.csv", split=("test" if i == 3 else "train") if split else None)
        if i == len(CONDITIONS) - 1:
            run = replace(run, spec=replace(run.spec, temperature_c=20.0,
                                            extra={**run.spec.extra, "temperature_measured": False}))
        runs.append(run)
    return Dataset(MachineSpec("t", {"y": axis.to_axis_spec((0.0, 200.0))}), tuple(runs))


def test_a_run_without_a_measured_temperature_is_not_held_out_as_the_most_extreme():
    ds = _dataset(Effects(), split=False)
    sp = choose_split(ds)
    assert "rt_4.csv" not in sp.test, sp.how
    # the measured spread (0.2 K) is too small to hold out by temperature: by feed
    assert sp.test == ("rt_3.csv",) and "feed" in sp.how


def test_a_run_without_a_measured_temperature_is_taken_at_the_measured_runs_mean():
    rts, _ = prepare_runs(_dataset(Effects(), split=True))
    by_file = {r.file: r for r in rts}
    assert not by_file["rt_4.csv"].temperature_measured
    assert abs(by_file["rt_4.csv"].temperature_c - np.mean([c[2] for c in CONDITIONS[:4]])) < 1e-9
    assert [by_file[f"rt_{i}.csv"].temperature_c for i in range(4)] == [c[2] for c in CONDITIONS[:4]]


def test_a_stand_in_temperature_is_no_temperature_step_for_the_thermal_family():
    # a lead grown by the machine's 25 °C (8 ppm/K, a static lead error at one temperature):
    # read at the stand-in's 20 °C the last train run would be a 5 K step for the
    # temperature form to fit
    rep = diagnose(_dataset(Effects(thermal=Thermal(lead_growth_ppm_per_k=8.0)), split=True),
                   GapSettings(keep_curves=False, second_effect=False))  # fmt: skip
    thermal = next(c for c in rep.candidates if c.effect == "thermal")
    assert not any(k.endswith("lead_growth_ppm_per_k") for k in thermal.params), thermal.params


def test_the_temperature_trend_of_the_runs_leaves_a_stand_in_out():
    from types import SimpleNamespace

    from core.gap.where import locate

    # the gap grows with the measured temperature; the unmeasured run's stand-in (20 °C
    # stored, a large gap) would turn the trend around
    runs = [SimpleNamespace(feed_mm_min=1000.0, acceleration_mm_s2=None, temperature_c=t, temperature_measured=m)
            for t, m in ((22.0, True), (24.0, True), (26.0, True), (28.0, True), (20.0, False))]
    resid = [np.full(10, g) for g in (1.0, 2.0, 3.0, 4.0, 9.0)]
    where = locate([], [], [], [], {}, {}, {}, list(zip(runs, resid)))
    assert where.details["r_run_rms_vs"]["temperature_c"] > 0.99


def test_a_history_of_few_measured_temperatures_holds_out_only_measured_ones():
    from core.dataset import Run, RunSpec

    # twelve round trips, two of them with a thermometer: a quarter would be three runs,
    # but only the two measured temperatures can be the most extreme
    specs = [RunSpec(f"rt_{i}.csv", "round_trip", ("y",), 1000.0, 20.0, extra={"temperature_measured": False})
             for i in range(10)]
    specs += [RunSpec(f"rt_{i}.csv", "round_trip", ("y",), 1000.0, t) for i, t in ((10, 23.0), (11, 26.0))]
    sp = choose_split(Dataset(MachineSpec("t", {}), tuple(Run(s, {}) for s in specs)))
    assert set(sp.test) == {"rt_10.csv", "rt_11.csv"} and "nan" not in sp.how, sp.how
