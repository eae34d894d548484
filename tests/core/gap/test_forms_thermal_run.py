"""A lead that grows during a run (the thermal family's warm-up form), on the twin: the
scale's mounting warms toward 40 µm/m with an 8 s time constant while 150 mm round trips
run. Named thermal, its gap halved and its size and time constant found, alone and
composed with a growth per kelvin; round trips each at its own constant temperature keep
the temperature form."""

import numpy as np
import pytest

from core.dataset import Dataset, MachineSpec
from core.errors import InputError
from core.gap import GapSettings, diagnose
from core.gap.data import RoundTrip
from core.gap.families.thermal import warmup_heat
from core.sim import AxisModel, Effects, Encoders, Thermal, round_trip, simulate

ENC = Encoders(table_noise_um=0.2, motor_noise_um=0.2)
ONE_TEMPERATURE = ((600.0, 400.0, 20.0), (1000.0, 600.0, 20.0), (1500.0, 800.0, 20.0), (2400.0, 1500.0, 20.0))
TEMPERATURES = ((600.0, 400.0, 17.0), (1000.0, 600.0, 20.0), (1500.0, 800.0, 23.0), (2400.0, 1500.0, 30.0))
WARMUP_UM_PER_M, WARMUP_TAU_S = 40.0, 8.0
SETTINGS = GapSettings(keep_curves=False, second_effect=False)


def _axis(thermal: Thermal) -> AxisModel:
    return AxisModel(name="y", transmission_mm_per_rev=6.857, backlash_um=60.0, effects=Effects(thermal=thermal),
                     encoders=ENC)  # fmt: skip


def _round_trips(thermal: Thermal, conditions) -> Dataset:
    """150 mm round trips at (feed mm/min, acceleration mm/s², temperature °C): the last
    one held out (the fastest, the shortest: least warmed up)."""
    axis, rng, runs = _axis(thermal), np.random.default_rng(7), []
    for i, (feed, acc, temp) in enumerate(conditions):
        start = (10.0, 30.0, 20.0, 40.0)[i]
        tr = simulate({"y": axis}, round_trip(start, start + 150.0, feed, acc, 0.5, axis="y"), temperature_c=temp,
                      rate_hz=500.0, rng=rng)  # fmt: skip
        runs.append(tr.to_run(f"rt_{i}.csv", split="test" if i == len(conditions) - 1 else "train"))
    return Dataset(MachineSpec("t", {"y": axis.to_axis_spec((0.0, 200.0))}), tuple(runs))


def test_the_twin_reads_the_warmup_on_the_scale():
    prog = round_trip(10.0, 160.0, 1000.0, 600.0, 0.5, axis="y")
    cold = simulate({"y": _axis(Thermal())}, prog, rate_hz=500.0, rng=np.random.default_rng(1))
    warm = simulate({"y": _axis(Thermal(warmup_um_per_m=WARMUP_UM_PER_M, warmup_tau_s=WARMUP_TAU_S))}, prog,
                    rate_hz=500.0, rng=np.random.default_rng(1))  # fmt: skip
    np.testing.assert_allclose(warm.table_true_mm["y"], cold.table_true_mm["y"], atol=1e-12)  # the table is not moved
    want_um = WARMUP_UM_PER_M * 1e-3 * -np.expm1(-warm.time_s / WARMUP_TAU_S) * warm.table_true_mm["y"]
    got_um = (warm.table_mm["y"] - cold.table_mm["y"]) * 1e3
    assert np.max(np.abs(got_um - want_um)) < 0.1  # the scale's quantum and the noise drawn alike
    assert np.max(want_um) > 4.0
    with pytest.raises(InputError, match="warmup_tau_s"):
        Thermal(warmup_tau_s=0.0)


def test_the_speed_law_warms_to_the_speed_in_m_per_min_with_its_time_constant():
    dt, v_mm_s = 0.002, 25.0  # 1.5 m/min
    t = np.arange(0.0, 20.0, dt)
    u = v_mm_s * t
    run = RoundTrip("r.csv", "y", "train", t, u, u.copy(), 20.0, 1500.0, None, 1, np.arange(t.size))
    h = warmup_heat(run, "speed", 2.0)
    assert h[0] == pytest.approx(0.0, abs=0.02)
    assert h[np.searchsorted(t, 2.0)] == pytest.approx(1.5 * (1 - np.exp(-1.0)), rel=0.02)
    assert h[-1] == pytest.approx(1.5, rel=0.01)
    assert warmup_heat(run, "time", 2.0)[np.searchsorted(t, 2.0)] == pytest.approx(1 - np.exp(-1.0), rel=0.01)


def test_a_warmup_at_one_temperature_is_named_thermal_its_gap_halved_and_its_size_found():
    rep = diagnose(_round_trips(Thermal(warmup_um_per_m=WARMUP_UM_PER_M, warmup_tau_s=WARMUP_TAU_S),
                                ONE_TEMPERATURE), SETTINGS)  # fmt: skip
    assert rep.effect == "thermal", rep.text()
    assert rep.gap_after_um <= 0.5 * rep.gap_before_um, rep.text()
    fitted = rep.candidates[0].params
    assert fitted["y.warmup_um_per_m"] == pytest.approx(WARMUP_UM_PER_M, rel=0.1), rep.text()
    assert fitted["y.warmup_tau_s"] == pytest.approx(WARMUP_TAU_S, rel=0.2), rep.text()


def test_a_warmup_composes_with_the_growth_per_kelvin():
    rep = diagnose(_round_trips(Thermal(lead_growth_ppm_per_k=8.0, warmup_um_per_m=WARMUP_UM_PER_M,
                                        warmup_tau_s=WARMUP_TAU_S), TEMPERATURES), SETTINGS)  # fmt: skip
    assert rep.effect == "thermal", rep.text()
    assert rep.gap_after_um <= 0.5 * rep.gap_before_um, rep.text()
    fitted = rep.candidates[0].params
    assert fitted["y.lead_growth_ppm_per_k"] == pytest.approx(8.0, abs=0.5), rep.text()
    assert fitted["y.warmup_um_per_m"] == pytest.approx(WARMUP_UM_PER_M, rel=0.1), rep.text()


def test_round_trips_each_at_a_constant_temperature_keep_the_temperature_form():
    rep = diagnose(_round_trips(Thermal(lead_growth_ppm_per_k=8.0, backlash_um_per_k=3.0), TEMPERATURES), SETTINGS)
    assert rep.effect == "thermal", rep.text()
    assert rep.gap_after_um <= 0.5 * rep.gap_before_um, rep.text()
    fitted = rep.candidates[0].params
    assert not any("warmup" in k for k in fitted), rep.text()
    assert fitted["y.lead_growth_ppm_per_k"] == pytest.approx(8.0, abs=0.5), rep.text()
