"""``mebm sim``: runs written as datasets, read back, and analysed by ``mebm analyze``."""

import json

import numpy as np
import pytest

from api.cli.main import main
from storage.dataset import read_dataset


def _sim(tmp_path, *args):
    return main(["sim", *args, "--out", str(tmp_path / "ds")])


def test_round_trip_writes_a_readable_run_with_useful_travel_inside_the_commanded_one(tmp_path):
    assert _sim(tmp_path, "round-trip", "--axis", "Y", "--travel-mm", "100", "--feed-mm-min", "2000",
                "--backlash-um", "50", "--rate-hz", "200", "--split", "train", "--utility-day", "3") == 0  # fmt: skip
    ds = read_dataset(tmp_path / "ds")
    assert ds.machine.id == "sim"
    assert ds.machine.axes["y"].travel_mm == (0.0, 100.0)
    run = ds.runs[0]
    assert run.spec.file == "rt_y_00.csv" and run.spec.kind == "round_trip" and run.spec.axes == ("y",)
    assert (run.spec.split, run.spec.utility_day, run.spec.feed_mm_min) == ("train", 3.0, 2000.0)
    cmd = run.command_mm("y")
    assert cmd.min() == pytest.approx(-5.0) and cmd.max() == pytest.approx(105.0)
    assert np.diff(run.time_s) == pytest.approx(np.full(len(run) - 1, 0.005))
    assert run.table_mm("y") == pytest.approx(cmd, abs=2000.0 / 60.0 / 10.0 + 0.05)  # lag v/K at most


def test_runs_append_to_one_dataset_and_keep_the_machine(tmp_path):
    assert _sim(tmp_path, "round-trip", "--axis", "x", "--travel-mm", "50", "--feed-mm-min", "3000") == 0
    assert _sim(tmp_path, "circle", "--radius-mm", "20", "--feed-mm-min", "1000", "--backlash-um", "30",
                "--effect", "x.servo_dynamics:velocity_lag_s=0.004", "--rate-hz", "250") == 0  # fmt: skip
    assert _sim(tmp_path, "line", "--angle-deg", "30", "--length-mm", "10", "--feed-mm-min", "600",
                "--rate-hz", "250") == 0  # fmt: skip
    ds = read_dataset(tmp_path / "ds")
    assert [r.spec.file for r in ds.runs] == ["rt_x_00.csv", "circle_00.csv", "line_00.csv"]
    assert ds.machine.axes["x"].travel_mm == (0.0, 50.0)  # kept from the first run
    circle_run = ds.runs[1]
    assert (circle_run.spec.radius_mm, circle_run.spec.direction, circle_run.spec.sweep_deg) == (20.0, "ccw", 360.0)
    assert circle_run.spec.extra["effects"]["x"]["servo_dynamics"]["velocity_lag_s"] == 0.004
    r = np.hypot(circle_run.table_mm("x"), circle_run.table_mm("y"))
    assert np.abs(r - 20.0).max() < 0.1  # steady lag R (1 - cos phi) = 69 µm plus the TBE
    assert ds.runs[2].spec.angle_deg == pytest.approx(30.0)


def test_json_summary_and_seeded_noise(tmp_path, capsys):
    args = ["round-trip", "--travel-mm", "20", "--feed-mm-min", "3000", "--table-noise-um", "0.5", "--seed", "4",
            "--json"]  # fmt: skip
    assert main(["sim", *args, "--out", str(tmp_path / "a")]) == 0
    summary = json.loads(capsys.readouterr().out)
    assert summary["file"] == "rt_y_00.csv" and summary["kind"] == "round_trip"
    assert summary["samples"] == len(read_dataset(tmp_path / "a").runs[0])
    assert main(["sim", *args, "--out", str(tmp_path / "b")]) == 0
    a = read_dataset(tmp_path / "a").runs[0].table_mm("y")
    b = read_dataset(tmp_path / "b").runs[0].table_mm("y")
    assert np.array_equal(a, b)


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["round-trip", "--feed-mm-min", "1000", "--effect", "friction:foo=1"], "no parameter 'foo'"),
        (["round-trip", "--feed-mm-min", "1000", "--effect", "wear:x=1"], "unknown effect category 'wear'"),
        (["round-trip", "--feed-mm-min", "-1"], "feed_mm_min (=-1.0)"),
        (["circle", "--radius-mm", "10", "--feed-mm-min", "100", "--axes", "x"], "--axes"),
        (["circle", "--radius-mm", "10", "--feed-mm-min", "100", "--effect", "z.thermal"], "axis 'z'"),
    ],
)
def test_bad_input_is_one_error_line_not_a_traceback(tmp_path, capsys, args, message):
    assert _sim(tmp_path, *args) == 1
    err = capsys.readouterr().err
    assert err.startswith("mebm sim: error:") and message in err
    assert "Traceback" not in err


def test_a_machine_that_differs_from_the_dataset_is_refused(tmp_path, capsys):
    assert _sim(tmp_path, "round-trip", "--travel-mm", "20", "--feed-mm-min", "3000") == 0
    assert _sim(tmp_path, "round-trip", "--travel-mm", "20", "--feed-mm-min", "3000", "--gain-per-s", "20") == 1
    assert "differs" in capsys.readouterr().err


def test_analyze_recovers_the_configured_backlash_and_lead_errors(tmp_path, capsys):
    b_um, ep_um_per_m, growth, temp = 120.0, -25.0, 1.5, 28.0
    cyclic = ((16.0, 3.0, 20.0), (6.857, 1.5, 70.0))
    effects = [
        "thermal:lead_error_um_per_m={},lead_growth_ppm_per_k={}".format(ep_um_per_m, growth),
        "cyclic_error:periods_mm={},amplitudes_um={},phases_deg={}".format(
            *("/".join(str(c[i]) for c in cyclic) for i in range(3))
        ),
    ]
    args = ["round-trip", "--travel-mm", "600", "--feed-mm-min", "1000", "--backlash-um", str(b_um),
            "--temperature-c", str(temp), "--table-resolution-um", "0.05", "--motor-counts-per-rev", "1048576",
            "--table-noise-um", "0.1"]  # fmt: skip
    for e in effects:
        args += ["--effect", e]
    assert _sim(tmp_path, *args) == 0
    capsys.readouterr()
    assert main(["analyze", str(tmp_path / "ds"), "--json", "--curves"]) == 0
    (res,) = json.loads(capsys.readouterr().out)
    assert res["backlash_mean_um"] == pytest.approx(b_um, abs=0.5)
    assert res["backlash_min_um"] > b_um - 0.5 and res["backlash_max_um"] < b_um + 0.5
    assert res["e_p_um_per_1000mm"] == pytest.approx(ep_um_per_m + growth * (temp - 20.0), abs=1.0)
    pos = np.array(res["curves"]["position_mm"])
    expected = sum(a * np.sin(2 * np.pi * pos / p + np.radians(ph)) for p, a, ph in cyclic)
    for stroke in ("positive", "negative"):
        dev = np.array(res["curves"][f"{stroke}_travel_deviation_um"])
        ok = np.isfinite(dev)
        residual = dev[ok] - expected[ok]
        residual -= np.polyval(np.polyfit(pos[ok], residual, 1), pos[ok])  # remove e_p and the alignment
        assert np.abs(residual).max() < 1.0
