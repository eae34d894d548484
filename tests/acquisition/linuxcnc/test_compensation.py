"""Compensation on a real controller, semi-closed (LinuxCNC's pid on the motor encoder):
mebm measures the round trip, ``mebm export-comp --format linuxcnc --comp-type 1`` writes
the table, LinuxCNC is restarted with it as the joint's COMP_FILE, mebm measures again.

The lost motion at the reversal (table minus commanded position, at rest after the
outward stroke and at rest after the return) must fall by at least 80 %; the mechanical
play the encoders see is unchanged (b̄ before = after), which is why mebm's maintenance
verification judges a loaded compensation on the compensated error. This module starts
LinuxCNC twice: the restart with the table is the point.
"""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from acquisition.cycle import run_cycle
from acquisition.linuxcnc.closed_loop import reversal_lost_motion_um
from acquisition.linuxcnc.sim import SimSettings
from acquisition.types import RoundTripProgram
from acquisition.url import driver_from_url
from core.dataset import MachineSpec
from core.maintenance import Figures, verify_repair
from core.tbe import MachiningTask, State, decide
from storage.dataset import append_runs
from tests.acquisition.linuxcnc.rig import AXIS, BACKLASH_UM, running_sim

ROOT = Path(__file__).resolve().parents[3]
#: Long dwells: the loop settles (exp(-K dwell) < 1e-6) before the rest is read.
PROGRAM = RoundTripProgram(-1.5, 13.5, 1200.0, acceleration_mm_s2=500.0, dwell_s=0.5)


def measure(sim):
    drv = driver_from_url(sim.url + "&trigger=active", timeout_s=2.0)
    r = run_cycle(drv, AXIS, PROGRAM)
    assert r.ok, r.reason
    return r, reversal_lost_motion_um(r.trace.table_mm, drv.last_command_mm, PROGRAM)


@pytest.fixture(scope="module")
def before_and_after(tmp_path_factory):
    folder = tmp_path_factory.mktemp("comp")
    with running_sim(SimSettings(backlash_um=BACKLASH_UM, loop="semi")) as sim:
        before, lost_before_um = measure(sim)
    append_runs(folder / "ds", MachineSpec("linuxcnc-sim", {"x": AXIS}), [before.to_run("rt_x_00.csv")])
    table = folder / "comp_x.txt"
    proc = subprocess.run([sys.executable, "-m", "api.cli", "export-comp", str(folder / "ds"), "--run", "rt_x_00.csv",
                           "--format", "linuxcnc", "--comp-type", "1", "--joint", "0", "--out", str(table)],
                          capture_output=True, text=True, cwd=ROOT, timeout=120)
    assert proc.returncode == 0, proc.stderr
    with running_sim(SimSettings(backlash_um=BACKLASH_UM, loop="semi", comp_file=str(table), comp_type=1)) as sim:
        assert "COMP_FILE = " in (sim.run_dir / "mebm_sim.ini").read_text()
        after, lost_after_um = measure(sim)
    return before, lost_before_um, after, lost_after_um, table


def test_before_the_table_the_reversal_loses_the_chain_s_backlash(before_and_after):
    before, lost_before_um, *_ = before_and_after
    assert abs(before.result.backlash_mean_um - BACKLASH_UM) <= 1.0
    assert lost_before_um == pytest.approx(BACKLASH_UM, abs=2.0)


def test_the_exported_table_loaded_as_comp_file_cuts_the_lost_motion_by_80_percent(before_and_after):
    _, lost_before_um, after, lost_after_um, table = before_and_after
    assert table.read_text().split("\n", 1)[0].split()[1:] == ["0.0600000", "-0.0600000"]  # ±b/2 trims
    assert lost_after_um <= 0.2 * lost_before_um, (lost_before_um, lost_after_um)
    # the play between motor and table is mechanical: the encoders still see it
    assert abs(after.result.backlash_mean_um - BACKLASH_UM) <= 1.0


def loaded_backlash_um(table) -> float:
    """The backlash the loaded table compensates: its trims' mean difference (moving + minus moving -)."""
    rows = [line.split() for line in table.read_text().splitlines() if line and not line.startswith("#")]
    return float(np.mean([float(r[1]) - float(r[2]) for r in rows])) * 1e3


def test_the_maintenance_verification_records_the_compensation_before_and_after(before_and_after):
    before, _, after, _, table = before_and_after
    task = MachiningTask("finish circle", "circle", feed_mm_min=2000.0, gain_per_s=AXIS.position_gain_per_s,
                         tolerance_um=20.0, radius_mm=50.0)
    assert decide(before.result.backlash_mean_um, [task]).state is not State.OK  # why the table was made

    def figures(r, measurement_id):
        return Figures(measurement_id, r.result.backlash_mean_um, r.uncertainty_um)

    v = verify_repair(figures(before, 1), figures(after, 2), [task], rule="guarded", warning_fraction=0.8,
                      compensated_backlash_um=loaded_backlash_um(table), compensation_source=table.name)
    assert v.passed, v.message
    assert v.to_dict()["before"]["backlash_mean_um"] == pytest.approx(v.to_dict()["after"]["backlash_mean_um"],
                                                                      abs=1.0)
    assert "compensated error" in v.against and table.name in v.against
