"""The gap diagnosis of a LinuxCNC dataset with FF1 on: two half circles (R 20 mm, 1000
mm/min to fit, 2000 mm/min to test) recorded on the simulated machine, full-closed, 1 µm
scales, LinuxCNC's pid feeding the commanded velocity forward (FF1 = 1). The nominal model
(P-only, K = P) misses them by the lag FF1 removes; the diagnosis must name
``servo_dynamics``. (P-only, the same diagnosis answers ``none``: test_circle.py.) One
LinuxCNC start for the module.
"""

from __future__ import annotations

import pytest

from acquisition.linuxcnc.sim import SimSettings
from core.gap import diagnose
from core.gap.diagnose import GapSettings
from tests.acquisition.linuxcnc.rig import AXIS, BACKLASH_UM, circles_dataset, running_sim

RADIUS_MM = 20.0
FEEDS = ((1000.0, "train"), (2000.0, "test"))


@pytest.fixture(scope="module")
def ff1_dataset():
    with running_sim(SimSettings(backlash_um=BACKLASH_UM, loop="full", ff1=1.0, scale_resolution_um=1.0,
                                 p_gain_per_s=AXIS.position_gain_per_s)) as sim:
        return circles_dataset(sim, RADIUS_MM, FEEDS)


def test_with_ff1_the_gap_diagnosis_names_servo_dynamics(ff1_dataset):
    settings = GapSettings(second_effect=False, keep_curves=False)
    report = diagnose(ff1_dataset, settings)
    assert report.effect == "servo_dynamics", report.text()
    assert report.gap_before_um > 10 * report.noise_floor_um  # far beyond the scales' noise
    assert report.gap_after_um <= (1 - settings.min_reduction) * report.gap_before_um
