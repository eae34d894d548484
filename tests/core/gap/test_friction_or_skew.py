"""Friction on a stiff chain and a latch skew, told apart by their signatures.

A Coulomb lost motion of a few µm on a stiff chain whose friction builds over a
pre-sliding length leaves its gap at the reversals: the chain unloads while the nut
crosses the gap and the table springs back. A latch skew leaves a gap that scales with
the speed on both strokes at constant feed. Each is named as itself, never as the other.
A stiff chain whose Coulomb lost motion grows with the feed (a viscous part over a
Stribeck curve) is named friction too: the skew's delay follows the viscous part, which
is the same function of speed, but not the Stribeck part's larger lost motion at low
speed.

The machines: one axis on the twin, quiet encoders (0.05 µm) so a few µm at the
reversals stand well above the floor; three train round trips and a faster test one
(the conditions of test_effects.py) at 250 Hz. Seeds 41 and 42, chosen before either
machine was diagnosed. On them: friction 0.24 -> 0.08 µm (the skew's fit 0.25 µm), the
skew 0.71 -> 0.07 µm (friction's fit 0.30-0.31 µm), the lost motion growing with feed
0.26 -> 0.07 µm by friction (the skew's fit 0.19 µm), floors 0.07 µm.
"""

import numpy as np
import pytest

from core.dataset import Dataset, MachineSpec
from core.gap import GapSettings, diagnose
from core.sim import AxisModel, Compliance, Effects, Encoders, Friction, SamplingSkew, round_trip, simulate

ENC = Encoders(table_noise_um=0.05, motor_noise_um=0.05)
CONDITIONS = ((600.0, 400.0, 17.0), (1000.0, 600.0, 20.0), (1500.0, 800.0, 23.0), (2400.0, 1500.0, 30.0))

# a 1000 N/µm chain, 2500 N Coulomb friction (lost motion 2 F_c / k = 5 µm) built over a
# pre-sliding length F_c / sigma_0 = 10 µm: the table springs back 0.69 x 10 µm at each reversal
STIFF_CHAIN_FRICTION = Effects(
    compliance=Compliance(stiffness_n_per_um=1000.0, table_mass_kg=500.0, damping_ratio=0.3),
    friction=Friction(coulomb_n=2500.0, model="lugre", bristle_stiffness_n_per_um=250.0),
)
# the same chain with Coulomb friction over a Stribeck curve (3000 N static, 3 mm/s) and a
# viscous part of 10 N s/mm: a lost motion of 5 µm that grows by 0.8 µm at the test feed
STIFF_CHAIN_VISCOUS = Effects(
    compliance=Compliance(stiffness_n_per_um=1000.0, table_mass_kg=500.0, damping_ratio=0.3),
    friction=Friction(coulomb_n=2500.0, static_n=3000.0, stribeck_velocity_mm_s=3.0, viscous_n_s_per_mm=10.0),
)
# 0.03 ms: 2 v tau = 2.4 µm of apparent backlash at the test feed, a gap of the same size
LATCH_SKEW = Effects(sampling_skew=SamplingSkew(table_delay_s=3e-5))


def round_trips(effects: Effects, seed: int, encoders: Encoders = ENC) -> Dataset:
    """One axis of the twin with ``effects``: three train round trips and a faster test one."""
    rng = np.random.default_rng(seed)
    axis = AxisModel(name="y", transmission_mm_per_rev=6.857, backlash_um=60.0, effects=effects, encoders=encoders)
    runs = []
    for i, (feed, acc, temp) in enumerate(CONDITIONS):
        start = (10.0, 40.0, 70.0, 30.0)[i]
        prog = round_trip(start, start + 100.0, feed, acc, 0.5, axis="y")
        tr = simulate({"y": axis}, prog, temperature_c=temp, rate_hz=250.0, rng=rng)
        runs.append(tr.to_run(f"rt_{i}.csv", split="test" if i == 3 else "train"))
    return Dataset(MachineSpec("t", {"y": axis.to_axis_spec((0.0, 200.0))}), tuple(runs))


@pytest.mark.parametrize("seed", (41, 42))
def test_friction_on_a_stiff_chain_is_named_friction_not_a_skew(seed):
    rep = diagnose(round_trips(STIFF_CHAIN_FRICTION, seed), GapSettings(keep_curves=False))
    assert rep.gap_before_um > 2.5 * rep.noise_floor_um, rep.text()  # it shows
    assert rep.where.details["rms_by_phase_um"]["reversal"] == max(rep.where.details["rms_by_phase_um"].values())
    assert rep.effect == "friction", rep.text()
    assert rep.gap_after_um <= 0.5 * rep.gap_before_um, rep.text()
    v = rep.candidates[0].values
    assert 5.0 <= v["y.presliding_length_um"] <= 20.0, v  # the pre-sliding form, about its true length
    skew = next(c for c in rep.candidates if c.effect == "sampling_skew")
    assert skew.gap_after_um > 0.75 * rep.gap_before_um, rep.text()  # the skew's form does not follow it


@pytest.mark.parametrize("seed", (41, 42))
def test_a_lost_motion_growing_with_feed_on_a_stiff_chain_is_named_friction_not_a_skew(seed):
    rep = diagnose(round_trips(STIFF_CHAIN_VISCOUS, seed), GapSettings(keep_curves=False))
    assert rep.gap_before_um > 2.5 * rep.noise_floor_um, rep.text()  # it shows
    assert rep.effect == "friction", rep.text()
    assert rep.gap_after_um <= 0.5 * rep.gap_before_um, rep.text()
    v = rep.candidates[0].values
    # the lost-motion form, with the chain's viscous part c / k = 0.01 µm per mm/s
    assert v["y.viscous_lost_motion_um_per_mm_s"] == pytest.approx(0.01, rel=0.3), v
    skew = next(c for c in rep.candidates if c.effect == "sampling_skew")
    assert 0.75 * skew.gap_after_um >= rep.gap_after_um, rep.text()  # told apart from the skew
    assert "sampling_skew" not in {a["effect"] for a in rep.to_dict()["close_alternatives"]}


@pytest.mark.parametrize("seed", (41, 42))
def test_a_latch_skew_is_named_a_skew_not_friction(seed):
    rep = diagnose(round_trips(LATCH_SKEW, seed), GapSettings(keep_curves=False))
    phases = rep.where.details["rms_by_phase_um"]
    assert phases["constant_velocity"] > 2 * phases["reversal"], phases  # the skew's signature: at speed
    assert rep.effect == "sampling_skew", rep.text()
    assert rep.gap_after_um <= 0.5 * rep.gap_before_um, rep.text()
    assert rep.candidates[0].values["y.table_delay_ms"] == pytest.approx(0.03, abs=0.005)
