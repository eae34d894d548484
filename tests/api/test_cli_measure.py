"""``mebm measure`` against ``mebm sim-controller`` in another process, and its failure modes."""

from __future__ import annotations

import json
import re
import select
import subprocess
import sys

import numpy as np
import pytest

from acquisition.measurement import default_program
from acquisition.sim.twin import CoreSimTwin
from api.cli.main import main
from core.dataset import AxisSpec, MachineSpec, Run, RunSpec
from core.sim import AxisModel, Effects, parse_effect
from storage.dataset import append_runs, read_dataset
from tests.ports import free_port

EFFECT = "cyclic_error:periods_mm=16/6.857,amplitudes_um=3/1.5"
LEAD_KEYS = ("e_p_um", "v_u_um", "v_300_um", "v_2pi_um")


def _reference_dataset(folder, axis: AxisSpec) -> None:
    """The twin's own noiseless trace of the same round trip, as a dataset for ``mebm analyze``."""
    cat, eff = parse_effect(EFFECT)
    model = AxisModel("y", transmission_mm_per_rev=6.857, screw_lead_mm=16.0, position_gain_per_s=10.0,
                      backlash_um=120.0, effects=Effects(**{cat: eff}))
    tr = CoreSimTwin(model).round_trip(default_program(axis, 1000.0), 1000.0)
    run = Run(RunSpec("twin.csv", "round_trip", ("y",), 1000.0, 20.0),
              {"time_s": tr.time_s, "y_motor_rev": tr.motor_rev, "y_table_mm": tr.table_mm})
    append_runs(folder, MachineSpec("twin", {"y": axis}), [run])


@pytest.mark.slow
def test_measure_a_simulated_controller_in_another_process(tmp_path, capsys):
    proc = subprocess.Popen(
        # time scale 3 with the largest trace buffer: 3.6 s of wall clock in the ring, more than
        # the 2 s a real controller's default buffer holds at 1 kHz. At time scale 10 (0.2 s)
        # a test process stalled by a loaded machine lost 2000 samples (correctly reported)
        [sys.executable, "-m", "api.cli", "sim-controller", "modbus", "--port", "0", "--time-scale", "3",
         "--ring-records", "10906", "--backlash-um", "120", "--effect", EFFECT, "--duration-s", "90"],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
    )
    try:
        ready, _, _ = select.select([proc.stdout], [], [], 60)
        assert ready, "sim-controller did not start within 60 s"
        line = proc.stdout.readline()
        port = int(re.search(r"modbus://127\.0\.0\.1:(\d+)", line).group(1))
        out = tmp_path / "measured"
        code = main(["measure", "--controller", f"sim://127.0.0.1:{port}", "--axis", "y", "--travel-mm", "100",
                     "--feed-mm-min", "1000", "--out", str(out), "--json", "--timeout-s", "2",
                     "--scale-accuracy-um", "2"])
        measured = json.loads(capsys.readouterr().out)
        assert code == 0, measured["reason"]
    finally:
        proc.terminate()
        proc.wait(10)
    assert measured["status"] == "ok" and measured["acquisition"]["lost_samples"] == 0
    ds = read_dataset(out)
    assert [r.spec.file for r in ds.runs] == [measured["file"]]
    assert ds.runs[0].spec.extra["latched"] is True
    # the scale it was measured with: in the budget and stated in the run
    assert ds.runs[0].spec.extra["instruments"]["scale_accuracy_um"] == 2.0
    scale = next(c for c in measured["result"]["uncertainty_budget"]["backlash_mean"]["components"]
                 if c["name"] == "scale")
    assert scale["standard_um"] == pytest.approx(2 / 3**0.5)
    # the same round trip, analysed by `mebm analyze` from the twin's own noiseless trace
    axis = AxisSpec("y", 6.857, 16.0, 10.0, (0.0, 100.0))
    _reference_dataset(tmp_path / "ref", axis)
    assert main(["analyze", str(tmp_path / "ref"), "--json"]) == 0
    reference = json.loads(capsys.readouterr().out)[0]
    got = measured["result"]
    assert got["backlash_mean_um"] == pytest.approx(reference["backlash_mean_um"], abs=1.0)
    assert reference["backlash_mean_um"] == pytest.approx(120.0, abs=1.0)
    for key in LEAD_KEYS:
        assert got[key] == pytest.approx(reference[key], abs=1.5), key
    # and `mebm analyze` of the measured dataset agrees with what measure printed
    assert main(["analyze", str(out), "--json"]) == 0
    again = json.loads(capsys.readouterr().out)[0]
    assert again["backlash_mean_um"] == pytest.approx(got["backlash_mean_um"], abs=1e-6)
    # with the same budget: the run's instruments are read back
    assert again["backlash_mean_uncertainty_um"] == pytest.approx(got["backlash_mean_uncertainty_um"], rel=1e-9)
    assert np.isfinite(again["v_2pi_um"])


def test_nothing_listening_fails_fast_with_one_line(tmp_path, capsys):
    # how few attempts a refused connection gets is counted in tests/acquisition/modbus/test_driver.py
    port = free_port()
    code = main(["measure", "--controller", f"modbus://127.0.0.1:{port}", "--travel-mm", "100",
                 "--feed-mm-min", "1000", "--out", str(tmp_path / "ds"), "--timeout-s", "1.5"])
    err = capsys.readouterr().err
    assert code != 0
    assert err.count("\n") == 1 and err.startswith("mebm measure: error: connection:")
    assert not (tmp_path / "ds").exists()  # nothing written for a failed cycle


def test_wrong_node_id_fails_within_the_timeout(tmp_path, capsys):
    from acquisition.sim.canopen.drive import SimCanopenDrive
    from acquisition.sim.twin import KinematicTwin

    with SimCanopenDrive(KinematicTwin(), node_id=5, channel="mebm-cli-wrong-node"):
        code = main(["measure", "--controller", "canopen://virtual/mebm-cli-wrong-node?node=6", "--travel-mm", "20",
                     "--feed-mm-min", "1000", "--out", str(tmp_path / "ds"), "--timeout-s", "1", "--json"])
    out, err = capsys.readouterr()
    assert code != 0 and "timeout" in err
    assert err.count("\n") == 1 and "node 6" in err
    assert json.loads(out)["status"] == "failed"


def test_bad_controller_url_is_a_usage_error(tmp_path, capsys):
    code = main(["measure", "--controller", "canopen://virtual/x", "--travel-mm", "20", "--feed-mm-min", "1000",
                 "--out", str(tmp_path / "ds")])
    assert code != 0 and "node=N" in capsys.readouterr().err


# CANopen end to end over real sockets (udp_multicast in a private network namespace, run in CI):
# tests/acquisition/canopen/test_driver_netns.py
