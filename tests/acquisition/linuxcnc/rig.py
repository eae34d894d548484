"""The LinuxCNC rig of the tests: a simulated machine (acquisition.linuxcnc.sim) run as an
unprivileged user the tests create, one at a time on this host (HAL is one per computer),
and what the tests do at it as its operator (e-stop, machine off, a program of its own).

Where LinuxCNC is not installed the tests skip with the reason; under ``CI=true`` they
fail (``.ci/run`` installs linuxcnc-uspace).
"""

from __future__ import annotations

import contextlib
import os
import pwd
import subprocess
import threading

import pytest

from acquisition.linuxcnc.closed_loop import DATA_ARC_DEG, from_the_radial_approach, half_circle_gcode
from acquisition.linuxcnc.contour import record_contour
from acquisition.linuxcnc.sim import LinuxcncSim, SimSettings, linuxcnc_available
from acquisition.types import RoundTripProgram
from core.dataset import AxisSpec, Dataset, MachineSpec, Run, RunSpec
from tests.host_lock import host_lock

USER = "mebm-linuxcnc"
#: The simulated X axis as mebm knows it (K is the sim's P).
AXIS = AxisSpec("x", 6.857, 16.0, 30.0, (0.0, 12.0))
PROGRAM = RoundTripProgram(-1.5, 13.5, 1200.0, acceleration_mm_s2=500.0, dwell_s=0.2)
BACKLASH_UM = 120.0


def unavailable(reason: str):
    if os.environ.get("CI", "").strip().lower() in ("1", "true", "yes"):
        pytest.fail(f"CI=true and the LinuxCNC tests cannot run: {reason}", pytrace=False)
    pytest.skip(reason)


def linuxcnc_user() -> str | None:
    """The unprivileged account LinuxCNC runs as (rtapi_app refuses root): created when this
    process is root and it does not exist; None when not root (LinuxCNC runs as this user)."""
    if os.geteuid() != 0:
        return None
    try:
        pwd.getpwnam(USER)
    except KeyError:
        proc = subprocess.run(["useradd", "--system", "--no-create-home", "--shell", "/usr/sbin/nologin", USER],
                              capture_output=True, text=True)
        if proc.returncode != 0 and "already exists" not in proc.stderr:
            unavailable(f"cannot create the user LinuxCNC runs as ({proc.stderr.strip()})")
    return USER


def one_linuxcnc_at_a_time():
    """The machine's one HAL, taken in turns while a test module's LinuxCNC runs."""
    return host_lock("linuxcnc")


@contextlib.contextmanager
def running_sim(settings: SimSettings = SimSettings(backlash_um=BACKLASH_UM), *, power_on: bool = True):
    """A started simulated machine (e-stop off, machine on), stopped at the end."""
    why = linuxcnc_available()
    if why:
        unavailable(why)
    user = linuxcnc_user()
    with one_linuxcnc_at_a_time():
        sim = LinuxcncSim(settings, user=user)
        sim.start()
        try:
            if power_on:
                sim.power_on()
            yield sim
        finally:
            sim.stop()


def run_operator_program(sim: LinuxcncSim, gcode: str) -> None:
    """The operator loads and runs a program of their own (not mebm's): AUTO mode, open, run."""
    path = sim.run_dir / "operator.ngc"
    path.write_text(gcode)
    path.chmod(0o644)
    replies = sim.rsh("set mode auto", f"set open {path}", "set run")
    assert all("ACK" in r and "NAK" not in r for r in replies), replies


#: LinuxCNC's Python module (linuxcnc-uspace installs it for the system's Python).
SYSTEM_PYTHON = "/usr/bin/python3"
_SWITCH_ON = """
import sys, time
try:
    import linuxcnc
except ImportError as exc:
    sys.exit(f"no module: {exc}")
c, s = linuxcnc.command(), linuxcnc.stat()
c.state(linuxcnc.STATE_ON)
end = time.monotonic() + float(sys.argv[1])
while True:
    s.poll()
    if s.task_state == linuxcnc.STATE_ON:
        break
    if time.monotonic() > end:
        sys.exit(f"LinuxCNC did not report the machine ON (task state {s.task_state})")
    time.sleep(0.02)
"""


def switch_on_elsewhere(timeout_s: float = 5.0) -> None:
    """The operator switches the machine on from an interface other than linuxcncrsh
    (LinuxCNC's Python module, as AXIS does); returns once LinuxCNC reports it ON. linuxcncrsh
    does not see it until its next ``get``."""
    proc = subprocess.run([SYSTEM_PYTHON, "-c", _SWITCH_ON, str(timeout_s)], capture_output=True, text=True,
                          timeout=timeout_s + 10.0, check=False)
    if proc.stderr.startswith("no module"):
        unavailable(f"LinuxCNC's Python module is not importable by {SYSTEM_PYTHON}: {proc.stderr.strip()}")
    assert proc.returncode == 0, proc.stderr.strip()[-500:]


def in_thread(fn, *args, **kwargs):
    """Run ``fn`` in a thread; returns (thread, result holder)."""
    out: dict = {}

    def body():
        try:
            out["value"] = fn(*args, **kwargs)
        except BaseException as exc:  # noqa: BLE001 - handed to the test
            out["error"] = exc

    t = threading.Thread(target=body, daemon=True)
    t.start()
    return t, out


def circles_dataset(sim: LinuxcncSim, radius_mm: float, feeds, recorded=None) -> Dataset:
    """The half circles at ``feeds`` ((feed, split), ...) as a dataset of both axes;
    ``recorded``: recordings already made, by feed."""
    ka = AXIS.transmission_mm_per_rev
    axes = {a: AxisSpec(a, ka, AXIS.screw_lead_mm, AXIS.position_gain_per_s, (-60.0, 60.0)) for a in "xy"}
    runs = []
    for i, (feed, split) in enumerate(feeds):
        rec = (recorded or {}).get(feed)
        if rec is None:
            program = sim.run_dir / f"circle_{i}.ngc"
            program.write_text(half_circle_gcode(radius_mm, feed))
            program.chmod(0o644)
            rec = record_contour("127.0.0.1", sim.settings.port, str(program))
        rec = from_the_radial_approach(rec)
        cols = {"time_s": rec.time_s}
        for k, a in enumerate("xy"):
            cols[f"{a}_motor_rev"] = rec.motor_mm[k] / ka
            cols[f"{a}_table_mm"] = rec.table_mm[k]
            cols[f"{a}_command_mm"] = rec.command_mm[k]
        runs.append(Run(RunSpec(f"circle_{i:02d}.csv", "circle", ("x", "y"), feed, 20.0, split=split,
                                radius_mm=radius_mm, centre_mm=(0.0, 0.0), direction="ccw",
                                start_angle_deg=DATA_ARC_DEG[0], sweep_deg=DATA_ARC_DEG[1]), cols))
    return Dataset(MachineSpec("linuxcnc-sim", axes), tuple(runs))
