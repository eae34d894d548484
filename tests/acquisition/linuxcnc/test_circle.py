"""The paper's closed loop on a real controller: LinuxCNC's pid closed on the linear scale
(full-closed), P only, on the simulated machine with a 120 µm backlash in X and Y and
linear scales of 1 µm resolution. mebm measures b̄ on a round trip of X; LinuxCNC then runs
a G3 half circle (R 50 mm, 2000 mm/min) through two quadrant transitions (X reverses at
0°, Y at 90°), recorded by the sampler of both axes. The radial error's bump after each
transition is the transient backlash error: it must agree with Eq. 8 evaluated at mebm's
b̄ within 10 %. With a second circle at 1500 mm/min to fit on, the gap diagnosis of the
two answers ``none``: the paper's P-only model explains LinuxCNC's loop to within the
scales' resolution. One LinuxCNC start for the module.
"""

from __future__ import annotations

import pytest

from acquisition.measurement import run_cycle
from acquisition.linuxcnc.closed_loop import half_circle_gcode, quadrant_bumps_um
from acquisition.linuxcnc.contour import record_contour
from acquisition.linuxcnc.sim import SimSettings
from acquisition.url import driver_from_url
from core.tbe.formulas import tbe_circle_um
from core.gap import diagnose
from core.gap.diagnose import GapSettings
from tests.acquisition.linuxcnc.rig import AXIS, BACKLASH_UM, PROGRAM, circles_dataset, running_sim

RADIUS_MM, FEED_MM_MIN = 50.0, 2000.0
TRAIN_FEED_MM_MIN = 1500.0
K_PER_S = AXIS.position_gain_per_s


@pytest.fixture(scope="module")
def measured():
    settings = SimSettings(backlash_um=BACKLASH_UM, loop="full", p_gain_per_s=K_PER_S, scale_resolution_um=1.0)
    with running_sim(settings) as sim:
        cycle = run_cycle(driver_from_url(sim.url + "&trigger=active", timeout_s=5.0), AXIS, PROGRAM)
        program = sim.run_dir / "circle.ngc"
        program.write_text(half_circle_gcode(RADIUS_MM, FEED_MM_MIN))
        program.chmod(0o644)
        circle = record_contour("127.0.0.1", sim.settings.port, str(program))
        dataset = circles_dataset(sim, RADIUS_MM, ((TRAIN_FEED_MM_MIN, "train"), (FEED_MM_MIN, "test")),
                                  recorded={FEED_MM_MIN: circle})
    return cycle, circle, dataset


def test_mebm_measures_the_chain_s_backlash_full_closed(measured):
    cycle, *_ = measured
    assert cycle.ok, cycle.reason
    assert abs(cycle.result.backlash_mean_um - BACKLASH_UM) <= 1.0, cycle.result.backlash_mean_um


def test_the_circle_s_quadrant_bumps_agree_with_eq_8_at_mebm_s_backlash(measured):
    cycle, rec, _ = measured
    assert cycle.ok, cycle.reason
    tbe_um = float(tbe_circle_um(cycle.result.backlash_mean_um, RADIUS_MM, FEED_MM_MIN, K_PER_S))
    bumps, between_um = quadrant_bumps_um(rec, RADIUS_MM, FEED_MM_MIN, K_PER_S)
    assert abs(between_um) < 0.05 * tbe_um  # away from the transitions the loop traces R cos φ
    for quadrant_deg, bump_um in bumps.items():  # X reverses at 0°, Y at 90°
        assert bump_um == pytest.approx(tbe_um, rel=0.10), (quadrant_deg, bump_um, tbe_um)


def test_p_only_the_gap_diagnosis_answers_none(measured):
    *_, dataset = measured
    settings = GapSettings(second_effect=False, keep_curves=False)
    report = diagnose(dataset, settings)
    assert report.effect == "none", report.text()
    # none because the nominal model explains the circles to within the scales' noise
    assert report.gap_before_um <= settings.noise_factor * report.noise_floor_um, report.text()
