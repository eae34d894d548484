"""Each effect, injected in simulated data, is named and its gap at least halved.

Small single-purpose datasets (the benchmark's are larger): round trips of one axis,
three to train and one to test at another feed, acceleration and temperature; circles
for servo dynamics, which round trips cannot see.
"""

import numpy as np
import pytest

from core.dataset import Dataset, MachineSpec
from core.gap import GapSettings, diagnose
from core.sim import (
    AxisModel,
    BacklashProfile,
    Compliance,
    CyclicError,
    Effects,
    Encoders,
    Friction,
    SamplingSkew,
    ServoDynamics,
    Thermal,
    circle,
    round_trip,
    simulate,
)

ENC = Encoders(table_noise_um=0.2, motor_noise_um=0.2)
TRAIN = ((600.0, 400.0, 17.0), (1000.0, 600.0, 20.0), (1500.0, 800.0, 23.0))  # feed, acceleration, temperature
TEST = (2400.0, 1500.0, 30.0)

EFFECTS = {
    "thermal": Effects(thermal=Thermal(lead_growth_ppm_per_k=8.0, backlash_um_per_k=3.0)),
    "backlash_profile": Effects(backlash_profile=BacklashProfile((0.0, 60.0, 110.0, 200.0), (50.0, 90.0, 70.0, 55.0))),
    "cyclic_error": Effects(cyclic_error=CyclicError.of((16.0, 4.0, 30.0), (11.3, 3.0, 100.0))),
    "friction": Effects(friction=Friction(coulomb_n=2500.0, static_n=3200.0, stribeck_velocity_mm_s=2.0,
                                          viscous_n_s_per_mm=10.0)),
    "compliance": Effects(compliance=Compliance(stiffness_n_per_um=60.0, table_mass_kg=1500.0, damping_ratio=0.3,
                                                guide_damping_n_s_per_mm=5.0)),
    "sampling_skew": Effects(sampling_skew=SamplingSkew(0.003)),
}


def _round_trip_runs(axis: AxisModel, rng, conditions=(*TRAIN, TEST), prefix: str = "rt") -> list:
    """Round trips of ``axis`` at ``conditions``: the first three train, the fourth test."""
    runs = []
    for i, (feed, acc, temp) in enumerate(conditions):
        start = (10.0, 40.0, 70.0, 30.0)[i]
        prog = round_trip(start, start + 100.0, feed, acc, 0.5, axis=axis.name)
        tr = simulate({axis.name: axis}, prog, temperature_c=temp, rate_hz=500.0, rng=rng)
        runs.append(tr.to_run(f"{prefix}_{i}.csv", split="test" if i == 3 else "train"))
    return runs


def _round_trips(effects: Effects, rng, conditions=(*TRAIN, TEST)) -> Dataset:
    axis = AxisModel(name="y", transmission_mm_per_rev=6.857, backlash_um=60.0, effects=effects, encoders=ENC)
    runs = _round_trip_runs(axis, rng, conditions)
    return Dataset(MachineSpec("t", {"y": axis.to_axis_spec((0.0, 200.0))}), tuple(runs))


@pytest.mark.parametrize("effect", sorted(EFFECTS))
def test_round_trip_effect_is_named_and_its_gap_halved(effect):
    conditions = (*TRAIN, TEST)
    if effect == "compliance":
        # The table floats across the backlash when braking harder than its guides hold it;
        # when it does depends steeply on the guide friction, which the apparent backlash
        # hides: a test braking harder than every train run is not predictable (see
        # docs/gap-diagnosis.md), so the test run brakes within the train range (and runs
        # slower than any train run: at a higher feed the float is as fragile).
        conditions = ((600.0, 400.0, 17.0), (1000.0, 1500.0, 20.0), (1500.0, 800.0, 23.0), (400.0, 800.0, 30.0))
    rep = diagnose(_round_trips(EFFECTS[effect], np.random.default_rng(7), conditions))
    assert rep.effect == effect, rep.text()
    assert rep.gap_after_um <= 0.5 * rep.gap_before_um, rep.text()
    assert rep.candidates[0].effect == effect
    assert rep.where.kind == "round_trip" and rep.where.axis == "y"


def test_a_static_lead_error_is_named_thermal_and_its_size_found():
    """The thermal family's temperature-independent form: a screw whose lead is 60 µm/m
    long at every temperature (the ISO 3408-3 mean travel deviation), no growth."""
    rep = diagnose(_round_trips(Effects(thermal=Thermal(lead_error_um_per_m=60.0)), np.random.default_rng(7)))
    assert rep.effect == "thermal", rep.text()
    assert rep.gap_after_um <= 0.5 * rep.gap_before_um, rep.text()
    fitted = rep.candidates[0].params
    assert fitted["y.lead_error_um_per_m"] == pytest.approx(60.0, abs=3.0), rep.text()
    assert abs(fitted["y.lead_growth_ppm_per_k"]) < 0.5, rep.text()


def test_the_fits_in_threads_give_the_report_of_the_fits_in_turn():
    """The candidates, and the second effects on top of the answer, fitted in threads:
    the same report as fitted one after the other."""
    ds = _round_trips(EFFECTS["friction"], np.random.default_rng(7))
    settings = GapSettings(keep_curves=False, noise_factor=1.0)  # a second effect is looked for above the floor
    rep = diagnose(ds, settings, workers=3)
    assert rep.pairs, rep.text()  # the second-effect step ran (its fits in threads too)
    assert diagnose(ds, settings, workers=1).to_dict() == rep.to_dict()


def test_servo_dynamics_is_named_from_circles_and_its_gap_halved():
    x = AxisModel(name="x", backlash_um=40.0, encoders=ENC,
                  effects=Effects(servo_dynamics=ServoDynamics(velocity_lag_s=0.008, dead_time_s=0.0015)))
    y = AxisModel(name="y", backlash_um=60.0, encoders=ENC)
    rng = np.random.default_rng(5)
    runs = []
    for i, (r, feed) in enumerate(((40.0, 800.0), (60.0, 1200.0), (30.0, 2500.0))):
        prog = circle(r, (100.0, 100.0), feed, "ccw" if i % 2 == 0 else "cw")
        tr = simulate({"x": x, "y": y}, prog, rate_hz=250.0, rng=rng)
        runs.append(tr.to_run(f"c_{i}.csv", split="test" if i == 2 else "train"))
    m = MachineSpec("t", {"x": x.to_axis_spec((0.0, 200.0)), "y": y.to_axis_spec((0.0, 200.0))})
    rep = diagnose(Dataset(m, tuple(runs)))
    assert rep.effect == "servo_dynamics", rep.text()
    assert rep.gap_after_um <= 0.5 * rep.gap_before_um
    best = rep.candidates[0]
    v = best.values

    def delay_ms(a):  # what a circle sees: the loop's total delay, however the fit splits it
        return v[f"{a}.velocity_lag_ms"] + v[f"{a}.dead_time_ms"] + v[f"{a}.feedback_delay_ms"]

    assert delay_ms("x") > 5.0 or v["x.position_gain_per_s"] < 0.8 * 10.0  # the slow axis is x
    assert delay_ms("y") < 2.0 or abs(v["y.position_gain_per_s"] - 10.0) < 1.0
    assert all(k.split(".")[0] in ("x", "y") for k in best.params)  # one stable shape: axis-prefixed
    for k, iv in best.intervals.items():  # a number is reported with its interval, or not at all
        assert (best.params[k] == "not identifiable") == (iv == "not identifiable")
        if iv != "not identifiable":
            assert iv[0] <= best.params[k] <= iv[1]
    assert rep.where.kind == "circle"


def test_friction_with_pre_sliding_is_named_from_circles_and_its_length_found():
    """LuGre friction (the force builds over a pre-sliding length F_c/sigma_0 = 20 µm): the
    round trips see its lost motion and the table's spring-back at each reversal (their
    pre-sliding form takes a length of about 28 µm on this 200 N/µm chain, whose inertia
    shows too), the circles its creep after each reversal, which the Karnopp form cannot
    follow (on the benchmark's seeds 3101/3102: contour gap 1.44 -> 1.36 µm with it,
    0.56 with pre-sliding).

    Without a viscous part: with one (6 N s/mm) friction alone cuts the whole gap by half
    only (1.47 -> 0.73 µm): the round trips' pre-sliding form has no viscous part, and the
    test round trip is faster than every train one (docs/gap-diagnosis.md, "Friction")."""
    fr = Friction(coulomb_n=2500.0, static_n=3000.0, stribeck_velocity_mm_s=3.0, viscous_n_s_per_mm=0.0,
                  model="lugre", bristle_stiffness_n_per_um=125.0)
    axes = {a: AxisModel(name=a, transmission_mm_per_rev=6.857, backlash_um=b, effects=Effects(friction=fr), encoders=ENC)
            for a, b in (("x", 40.0), ("y", 90.0))}  # fmt: skip
    rng = np.random.default_rng(11)
    runs = [r for a in axes for r in _round_trip_runs(axes[a], rng, prefix=f"rt_{a}")]
    # train circles of 20-30 mm: what shows friction is each reversal (the feed there), not
    # the arcs between; on 40-60 mm ones the report is the same to the third digit
    for i, (r, feed) in enumerate(((20.0, 600.0), (30.0, 1000.0), (25.0, 1400.0), (30.0, 2400.0))):
        tr = simulate(axes, circle(r, (100.0, 100.0), feed, "ccw" if i % 2 == 0 else "cw"), rate_hz=500.0, rng=rng)
        runs.append(tr.to_run(f"c_{i}.csv", split="test" if i == 3 else "train"))
    m = MachineSpec("t", {a: ax.to_axis_spec((0.0, 200.0)) for a, ax in axes.items()})
    # noise factor 1.5: friction leaves 0.47 µm on a 0.25 µm floor, at the default 2x's edge
    # (a fit a little closer falls under it: the second-effect step would not run and the
    # last assertion would have nothing to check); the fits do not depend on it
    rep = diagnose(Dataset(m, tuple(runs)), GapSettings(noise_factor=1.5))
    assert rep.effect == "friction", rep.text()
    assert rep.gap_after_um <= 0.5 * rep.gap_before_um, rep.text()
    p = rep.candidates[0].values
    for a in axes:  # the pre-sliding form was kept, with about the true length (20 µm)
        assert 10.0 <= p[f"{a}.presliding_um"] <= 40.0, {k: v for k, v in p.items() if k.startswith(a)}
    # a second effect tried on top keeps friction's contour refit (it is not fitted again)
    on_top = [c for c in rep.pairs if c.effect.startswith("friction+")]
    assert on_top, rep.text()
    for c in on_top:
        for a in axes:
            assert c.values[f"{a}.presliding_um"] == p[f"{a}.presliding_um"], c.effect


def test_a_weak_cut_is_named_as_such():
    """When nothing cuts the gap by ``min_reduction``, the best single candidate is still
    named if it cuts by ``min_first_reduction``, and the decision says that most of the gap
    stays unexplained. The thermal dataset's own cut is above a half (its halving test
    above): at a main threshold of 99 % it fails the main rule and passes a weak one of a
    half. The decision on either side of the thresholds: tests/core/gap/test_select.py."""
    ds = _round_trips(EFFECTS["thermal"], np.random.default_rng(7))
    weak = diagnose(ds, GapSettings(keep_curves=False, second_effect=False, min_reduction=0.99,
                                    min_first_reduction=0.5))  # fmt: skip
    assert weak.effect == "thermal" and weak.effects == ("thermal",), weak.text()
    assert " only (under 99 %)" in weak.decision and "most of the gap stays unexplained" in weak.decision
    assert weak.gap_after_um <= 0.5 * weak.gap_before_um and weak.second_effect == ""
    d = weak.to_dict()
    assert d["thresholds"]["min_first_reduction"] == 0.5 and d["selection"]["kind"] == "weak"


def test_a_nominal_machine_with_a_coarse_scale_is_none_within_twice_its_floor():
    """A 1 µm linear scale and a 2^16-count motor encoder: the quantization alone gives
    0.29 µm RMS, which the noise floor reads from the records' own steps."""
    axis = AxisModel(name="y", transmission_mm_per_rev=6.857, backlash_um=60.0,
                     encoders=Encoders(table_noise_um=0.05, motor_noise_um=0.05, motor_counts_per_rev=2**16,
                                       table_resolution_um=1.0))  # fmt: skip
    runs = _round_trip_runs(axis, np.random.default_rng(13))
    rep = diagnose(Dataset(MachineSpec("t", {"y": axis.to_axis_spec((0.0, 200.0))}), tuple(runs)),
                   GapSettings(keep_curves=False))  # fmt: skip
    assert rep.effect == "none", rep.text()
    assert rep.noise_floor_um >= 0.29, rep.text()
    assert rep.gap_before_um <= 2.0 * rep.noise_floor_um, rep.text()
