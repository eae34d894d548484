"""The gap diagnosis of a LinuxCNC dataset: two half circles (R 20 mm, 1000 mm/min to fit,
2000 mm/min to test) recorded on the simulated machine, full-closed, with LinuxCNC's pid
feeding the commanded velocity forward (FF1 = 1). The nominal model (P-only, K = P) misses
them by the lag FF1 removes; the diagnosis must name ``servo_dynamics``. One LinuxCNC
start for the module.
"""

from __future__ import annotations

import pytest

from acquisition.linuxcnc.closed_loop import half_circle_gcode
from acquisition.linuxcnc.contour import record_contour
from acquisition.linuxcnc.sim import SimSettings
from core.dataset import AxisSpec, Dataset, MachineSpec, Run, RunSpec
from core.gap import diagnose
from core.gap.diagnose import GapSettings
from tests.acquisition.linuxcnc.rig import AXIS, BACKLASH_UM, running_sim

RADIUS_MM = 20.0
FEEDS = ((1000.0, "train"), (2000.0, "test"))


def circles_dataset(sim) -> Dataset:
    ka = AXIS.transmission_mm_per_rev
    axes = {a: AxisSpec(a, ka, AXIS.screw_lead_mm, AXIS.position_gain_per_s, (-60.0, 60.0)) for a in "xy"}
    runs = []
    for i, (feed, split) in enumerate(FEEDS):
        program = sim.run_dir / f"circle_{i}.ngc"
        program.write_text(half_circle_gcode(RADIUS_MM, feed))
        program.chmod(0o644)
        rec = record_contour("127.0.0.1", sim.settings.port, str(program))
        cols = {"time_s": rec.time_s}
        for k, a in enumerate("xy"):
            cols[f"{a}_motor_rev"] = rec.motor_mm[k] / ka
            cols[f"{a}_table_mm"] = rec.table_mm[k]
            cols[f"{a}_command_mm"] = rec.command_mm[k]
        runs.append(Run(RunSpec(f"circle_{i:02d}.csv", "circle", ("x", "y"), feed, 20.0, split=split,
                                radius_mm=RADIUS_MM, centre_mm=(0.0, 0.0), direction="ccw", start_angle_deg=-45.0,
                                sweep_deg=180.0), cols))
    return Dataset(MachineSpec("linuxcnc-sim", axes), tuple(runs))


@pytest.fixture(scope="module")
def ff1_dataset():
    with running_sim(SimSettings(backlash_um=BACKLASH_UM, loop="full", ff1=1.0,
                                 p_gain_per_s=AXIS.position_gain_per_s)) as sim:
        return circles_dataset(sim)


def test_with_ff1_the_gap_diagnosis_names_servo_dynamics(ff1_dataset):
    report = diagnose(ff1_dataset, GapSettings(second_effect=False, keep_curves=False))
    assert report.effect == "servo_dynamics", report.text()
    assert report.gap_after_um < 0.25 * report.gap_before_um
