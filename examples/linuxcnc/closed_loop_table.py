"""The README's LinuxCNC closed-loop table: mebm and the paper's model against LinuxCNC
running mebm's simulated machine (acquisition/linuxcnc/sim). Needs linuxcnc-uspace; as
root, give the account LinuxCNC runs as (rtapi_app refuses root):

    .venv/bin/python examples/linuxcnc/closed_loop_table.py [--user mebm-linuxcnc]

Prints one Markdown table: b̄ against the chain's backlash (semi- and full-closed), the
circle's quadrant bumps against Eq. 8 at mebm's b̄, the reversal's lost motion before and
after the table of ``mebm export-comp --format linuxcnc --comp-type 1`` is loaded as
COMP_FILE, and the gap diagnosis' answer with FF1 off and on (1 µm scales in the
full-closed runs). About a minute and a half.
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import tempfile
from pathlib import Path


from acquisition.measurement import run_cycle
from acquisition.linuxcnc.closed_loop import (
    DATA_ARC_DEG,
    from_the_radial_approach,
    half_circle_gcode,
    quadrant_bumps_um,
    reversal_lost_motion_um,
)
from acquisition.linuxcnc.contour import record_contour
from acquisition.linuxcnc.sim import LinuxcncSim, SimSettings
from acquisition.types import RoundTripProgram
from acquisition.url import driver_from_url
from core.dataset import AxisSpec, Dataset, MachineSpec, Run, RunSpec
from core.gap import diagnose
from core.gap.diagnose import GapSettings
from core.tbe.formulas import tbe_circle_um
from storage.dataset import append_runs

ROOT = Path(__file__).resolve().parents[2]
B_UM, K = 120.0, 30.0
AXIS = AxisSpec("x", 6.857, 16.0, K, (0.0, 12.0))
PROGRAM = RoundTripProgram(-1.5, 13.5, 1200.0, acceleration_mm_s2=500.0, dwell_s=0.5)
R_MM, F_MM_MIN = 50.0, 2000.0


def round_trip(sim):
    drv = driver_from_url(sim.url + "&trigger=active", timeout_s=2.0)
    r = run_cycle(drv, AXIS, PROGRAM)
    if not r.ok:
        raise SystemExit(f"round trip failed: {r.reason}")
    return r, reversal_lost_motion_um(r.trace.table_mm, drv.last_command_mm, PROGRAM)


def program(sim, name: str, radius_mm: float, feed: float):
    path = sim.run_dir / name
    path.write_text(half_circle_gcode(radius_mm, feed))
    path.chmod(0o644)
    return record_contour("127.0.0.1", sim.settings.port, str(path))


def gap_answer(sim, radius_mm: float, feeds, recorded=None) -> str:
    """The gap diagnosis of half circles at ``feeds`` ((feed, split), ...): its answer."""
    ka = AXIS.transmission_mm_per_rev
    axes = {a: AxisSpec(a, ka, 16.0, K, (-60.0, 60.0)) for a in "xy"}
    runs = []
    for i, (feed, split) in enumerate(feeds):
        rec = (recorded or {}).get(feed) or program(sim, f"gap_{i}.ngc", radius_mm, feed)
        rec = from_the_radial_approach(rec)
        cols = {"time_s": rec.time_s}
        for k, a in enumerate("xy"):
            cols.update({f"{a}_motor_rev": rec.motor_mm[k] / ka, f"{a}_table_mm": rec.table_mm[k],
                         f"{a}_command_mm": rec.command_mm[k]})
        runs.append(Run(RunSpec(f"circle_{i:02d}.csv", "circle", ("x", "y"), feed, 20.0, split=split,
                                radius_mm=radius_mm, centre_mm=(0.0, 0.0), direction="ccw",
                                start_angle_deg=DATA_ARC_DEG[0], sweep_deg=DATA_ARC_DEG[1]), cols))
    rep = diagnose(Dataset(MachineSpec("linuxcnc-sim", axes), tuple(runs)),
                   GapSettings(second_effect=False, keep_curves=False))
    return (f"`{rep.effect}` (test gap {rep.gap_before_um:.2f} µm, noise floor {rep.noise_floor_um:.2f} µm, "
            f"after {rep.gap_after_um:.2f} µm)")


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--user", default=None, help="the account LinuxCNC runs as when this runs as root")
    a = ap.parse_args()
    rows = []
    tmp = Path(tempfile.mkdtemp(prefix="mebm-closed-loop-"))
    with LinuxcncSim(SimSettings(backlash_um=B_UM, loop="semi"), user=a.user) as sim:
        sim.power_on()
        semi, lost_before = round_trip(sim)
    append_runs(tmp / "ds", MachineSpec("linuxcnc-sim", {"x": AXIS}), [semi.to_run("rt_x_00.csv")])
    table = tmp / "comp_x.txt"
    subprocess.run([sys.executable, "-m", "api.cli", "export-comp", str(tmp / "ds"), "--run", "rt_x_00.csv",
                    "--format", "linuxcnc", "--comp-type", "1", "--joint", "0", "--out", str(table)], check=True,
                   cwd=ROOT, stdout=subprocess.DEVNULL)
    with LinuxcncSim(SimSettings(backlash_um=B_UM, loop="semi", comp_file=str(table)), user=a.user) as sim:
        sim.power_on()
        comp, lost_after = round_trip(sim)
    with LinuxcncSim(SimSettings(backlash_um=B_UM, loop="full", scale_resolution_um=1.0), user=a.user) as sim:
        sim.power_on()
        full, _ = round_trip(sim)
        circle = program(sim, "circle.ngc", R_MM, F_MM_MIN)
        bumps, _ = quadrant_bumps_um(circle, R_MM, F_MM_MIN, K)
        gap_p = gap_answer(sim, R_MM, ((1500.0, "train"), (F_MM_MIN, "test")), recorded={F_MM_MIN: circle})
    with LinuxcncSim(SimSettings(backlash_um=B_UM, loop="full", ff1=1.0, scale_resolution_um=1.0),
                     user=a.user) as sim:
        sim.power_on()
        gap_ff1 = gap_answer(sim, 20.0, ((1000.0, "train"), (2000.0, "test")))
    tbe = float(tbe_circle_um(full.result.backlash_mean_um, R_MM, F_MM_MIN, K))
    rows.append(("b̄, semi-closed (chain 120 µm)", f"{semi.result.backlash_mean_um:.2f} µm"))
    rows.append(("b̄, full-closed, 1 µm scales (chain 120 µm)", f"{full.result.backlash_mean_um:.2f} µm"))
    rows.append((f"circle R {R_MM:g} mm at {F_MM_MIN:g} mm/min, full-closed P-only: Eq. 8 at b̄",
                 f"{tbe:.1f} µm"))
    for q, bump in bumps.items():
        rows.append((f"  measured bump after {q:g}°", f"{bump:.1f} µm ({(bump / tbe - 1) * 100:+.1f} %)"))
    rows.append(("lost motion at the reversal, semi-closed, no table", f"{lost_before:.1f} µm"))
    rows.append(("  with mebm export-comp's type-1 table as COMP_FILE",
                 f"{lost_after:.2f} µm ({(lost_after / lost_before - 1) * 100:+.1f} %); b̄ {comp.result.backlash_mean_um:.2f} µm"))
    rows.append((f"gap diagnosis, full-closed P-only (R {R_MM:g} mm, 1500/2000 mm/min)", gap_p))
    rows.append(("gap diagnosis, full-closed FF1 = 1 (R 20 mm, 1000/2000 mm/min)", gap_ff1))
    print("| quantity | LinuxCNC 2.9 (simulated machine) |\n|---|---|")
    for k, v in rows:
        print(f"| {k} | {v} |")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
