"""`mebm tbe` and `mebm analyze` as a user calls them."""

import json
import math

import numpy as np
import pytest

from api.cli.main import main
from core.dataset import AxisSpec, Dataset, MachineSpec, Run, RunSpec
from storage.dataset import write_dataset
from tests.core.criteria.synth import round_trip


def run_cli(capsys, *argv):
    code = main(list(argv))
    out, err = capsys.readouterr()
    return code, out, err


def test_tbe_limit_gives_paper_236(capsys):
    code, out, _ = run_cli(capsys, "tbe", "limit", "--tolerance-um", "45", "--radius-mm", "200",
                           "--feed-mm-min", "200", "--gain-per-s", "10", "--json")
    assert code == 0
    assert json.loads(out)["backlash_limit_um"] == pytest.approx(236.0, abs=0.1)


def test_tbe_limit_answers_at_the_edge_of_eq_8(capsys):
    # the domain edge landed just past ωT = π/2 and the command refused
    code, out, err = run_cli(capsys, "tbe", "limit", "--tolerance-um", "10", "--radius-mm", "5",
                             "--feed-mm-min", "2226.5", "--gain-per-s", "5", "--json")
    assert (code, err) == (0, "")
    assert json.loads(out)["backlash_limit_um"] == pytest.approx(10.233, abs=0.001)


def test_tbe_circle_json_and_text(capsys):
    code, out, _ = run_cli(capsys, "tbe", "circle", "--backlash-um", "240.1", "--radius-mm", "200",
                           "--feed-mm-min", "200", "--gain-per-s", "10", "--json")
    assert code == 0
    d = json.loads(out)
    assert d["tbe_um"] == pytest.approx(45.55, abs=0.02)
    assert d["radial_peak_from_programmed_um"] == pytest.approx(d["tbe_um"] - d["steady_lag_um"])
    code, out, _ = run_cli(capsys, "tbe", "circle", "--backlash-um", "240.1", "--radius-mm", "200",
                           "--feed-mm-min", "200", "--gain-per-s", "10")
    assert "45.55 µm" in out


def test_tbe_line(capsys):
    code, out, _ = run_cli(capsys, "tbe", "line", "--backlash-um", "236", "--angle-deg", "45",
                           "--feed-mm-min", "200", "--gain-per-s", "10", "--json")
    assert code == 0 and json.loads(out)["tbe_um"] == pytest.approx(109.67, abs=0.02)


@pytest.mark.parametrize(
    "argv",
    [
        ["tbe", "circle", "--backlash-um", "100", "--radius-mm", "200", "--feed-mm-min", "0", "--gain-per-s", "10"],
        ["tbe", "limit", "--tolerance-um", "-5", "--radius-mm", "200", "--feed-mm-min", "200", "--gain-per-s", "10"],
        ["tbe", "limit", "--tolerance-um", "1e7", "--radius-mm", "200", "--feed-mm-min", "200", "--gain-per-s", "10"],
        ["tbe", "line", "--backlash-um", "nan", "--angle-deg", "45", "--feed-mm-min", "200", "--gain-per-s", "10"],
    ],
)
def test_bad_values_give_one_line_and_nonzero_exit(capsys, argv):
    code, out, err = run_cli(capsys, *argv)
    assert code != 0
    assert err.startswith("mebm tbe: error: ")
    assert err.count("\n") == 1 and "Traceback" not in err


def _dataset(tmp_path, *runs):
    axis = AxisSpec("y", 6.857, 16.0, 10.0, (0.0, 300.0))
    folder = tmp_path / "ds"
    write_dataset(folder, Dataset(MachineSpec("vmc-850", {"y": axis}), tuple(runs)))
    return folder


def _rt_run(name, b_um, feed=2000, end_mm=305.0):
    s = round_trip(start_mm=-5.0, end_mm=end_mm, feed_mm_min=feed, backlash_um=lambda u: b_um + 0 * u,
                   lead_error_um=lambda u: 3 * np.sin(2 * np.pi * u / 16), rng=np.random.default_rng(1))
    spec = RunSpec(file=name, kind="round_trip", axes=("y",), feed_mm_min=feed, temperature_c=21.5, utility_day=3)
    return Run(spec, {"time_s": s.time_s, "y_motor_rev": s.motor_rev, "y_table_mm": s.table_mm})


def test_analyze_json_has_the_contract_keys(tmp_path, capsys):
    folder = _dataset(tmp_path, _rt_run("rt_00.csv", 120.0), _rt_run("rt_01.csv", 200.0))
    code, out, _ = run_cli(capsys, "analyze", str(folder), "--json")
    assert code == 0
    rows = json.loads(out)
    assert [r["file"] for r in rows] == ["rt_00.csv", "rt_01.csv"]
    for r, b in zip(rows, (120.0, 200.0)):
        for key in ("file", "axis", "backlash_mean_um", "backlash_min_um", "backlash_max_um",
                    "e_p_um", "v_u_um", "v_300_um", "v_2pi_um", "strokes"):
            assert key in r
        assert r["backlash_mean_um"] == pytest.approx(b, abs=0.5)
        assert set(r["strokes"]) == {"positive", "negative"}
        assert r["temperature_c"] == 21.5
        # the GUM budget's expanded (k = 2) figures
        # (the default glass scale's ±1 µm short-range accuracy, k = 2, and the data's part below 0.5 µm)
        scale = 2 / math.sqrt(3)
        assert scale < r["backlash_mean_uncertainty_um"] < math.hypot(scale, 0.5)
        for key in ("e_p", "v_u", "v_300", "v_2pi"):
            assert r[f"{key}_uncertainty_um"] > 0
        assert r["uncertainty_budget"]["backlash_mean"]["coverage_factor"] == 2.0
        assert r["outliers_removed"] == 0 and r["grid_step_mm"] == 0.25


def test_analyze_states_the_scale_and_the_thermometer_and_takes_them_as_options(tmp_path, capsys):
    folder = _dataset(tmp_path, _rt_run("rt_00.csv", 120.0))
    code, out, _ = run_cli(capsys, "analyze", str(folder), "--json")
    assert code == 0
    (r,) = json.loads(out)
    comp = {c["name"]: c for c in r["uncertainty_budget"]["backlash_mean"]["components"]}
    assert comp["scale"]["standard_um"] == pytest.approx(1 / math.sqrt(3))
    # the run's 21.5 °C: a Pt100 of class B, ±(0.30 + 0.005 x 21.5) °C
    assert "±0.41 °C at 21.5 °C" in comp["temperature"]["note"] and comp["temperature"]["standard_um"] > 0
    code, out, _ = run_cli(capsys, "analyze", str(folder), "--json", "--scale-accuracy-um", "3",
                           "--thermometer-class", "A")
    assert code == 0
    (r,) = json.loads(out)
    comp = {c["name"]: c for c in r["uncertainty_budget"]["backlash_mean"]["components"]}
    assert comp["scale"]["standard_um"] == pytest.approx(3 / math.sqrt(3))
    assert "class A" in comp["temperature"]["note"]
    assert r["backlash_mean_uncertainty_um"] > 2 * 3 / math.sqrt(3)


def test_analyze_table_output(tmp_path, capsys):
    folder = _dataset(tmp_path, _rt_run("rt_00.csv", 120.0))
    code, out, _ = run_cli(capsys, "analyze", str(folder))
    assert code == 0
    assert "b̄ (µm)" in out and "rt_00.csv" in out and "120.0" in out
    assert ("e_p: mean travel deviation; v_u: travel variation over the useful travel; "
            "v_300: travel variation within 300 mm; v_2π: travel variation within one revolution (2π rad)") in out


def test_analyze_reports_bad_run_by_name_and_keeps_the_good_one(tmp_path, capsys):
    folder = _dataset(tmp_path, _rt_run("good.csv", 120.0), _rt_run("short.csv", 120.0, end_mm=200.0))
    code, out, err = run_cli(capsys, "analyze", str(folder), "--json")
    assert code == 1
    assert [r["file"] for r in json.loads(out)] == ["good.csv"]
    assert "short.csv (axis y)" in err and "shorter than the useful travel" in err
    # the cause once, on one line that ends the output
    assert err.count("shorter than the useful travel") == 1 and err.endswith("\n")
    assert err.count("\n") == 1


def test_analyze_sparse_trace_is_not_refused_and_reports_its_grid(tmp_path, capsys):
    # 8000 mm/min at 200 Hz: 0.67 mm between samples is analysed, not refused
    s = round_trip(start_mm=-20.0, end_mm=320.0, feed_mm_min=8000, rate_hz=200.0, backlash_um=lambda u: 6 + 0 * u,
                   lead_error_um=lambda u: 3 * np.sin(2 * np.pi * u / 16), rng=np.random.default_rng(1))
    spec = RunSpec(file="sparse.csv", kind="round_trip", axes=("y",), feed_mm_min=8000, temperature_c=20.0)
    folder = _dataset(tmp_path, Run(spec, {"time_s": s.time_s, "y_motor_rev": s.motor_rev, "y_table_mm": s.table_mm}))
    code, out, err = run_cli(capsys, "analyze", str(folder), "--json")
    assert (code, err) == (0, "")
    row = json.loads(out)[0]
    assert row["backlash_mean_um"] == pytest.approx(6.0, abs=0.5)
    assert row["grid_step_mm"] == 0.25 and row["sample_spacing_mm"] == pytest.approx(0.667, abs=0.01)


def test_analyze_malformed_dataset_names_file_and_row(tmp_path, capsys):
    folder = _dataset(tmp_path, _rt_run("rt_00.csv", 120.0))
    lines = (folder / "rt_00.csv").read_text().splitlines()
    lines[5] = lines[5].split(",", 1)[0] + ",abc," + lines[5].split(",", 2)[2]
    (folder / "rt_00.csv").write_text("\n".join(lines) + "\n")
    code, _, err = run_cli(capsys, "analyze", str(folder))
    assert code != 0
    assert "rt_00.csv, row 5" in err and "'abc'" in err
    assert "Traceback" not in err


def test_analyze_missing_folder(tmp_path, capsys):
    code, _, err = run_cli(capsys, "analyze", str(tmp_path / "nope"))
    assert code != 0 and "not a folder" in err


def test_analyze_reports_the_reversal_values_and_the_datasets_clearance(capsys, tmp_path):
    # two runs at different feeds on a twin with friction; the lost
    # motion's feed-independent part is the clearance (20 µm) plus the Coulomb wind-up
    # 2 F_c / k = 2 x 1000 N / 200 N/µm = 10 µm
    out_dir = tmp_path / "ds"
    for feed in ("1000", "4000"):
        code, _, err = run_cli(capsys, "sim", "round-trip", "--travel-mm", "60", "--feed-mm-min", feed,
                               "--backlash-um", "20", "--effect", "friction:coulomb_n=1000,viscous_n_s_per_mm=5",
                               "--effect", "compliance:stiffness_n_per_um=200", "--rate-hz", "500",
                               "--out", str(out_dir))
        assert code == 0, err
    code, out, _ = run_cli(capsys, "analyze", str(out_dir), "--json")
    assert code == 0
    runs = json.loads(out)
    for r in runs:
        assert r["reversal_mean_um"] == pytest.approx(r["backlash_mean_um"], abs=0.5)
        assert r["reversal_max_um"] >= r["reversal_mean_um"] - 1e-9
    c = runs[0]["lost_motion"]["clearance_dataset"]
    assert c["clearance_um"] == pytest.approx(30.0, abs=0.5) and "Coulomb" in c["reason"]
    code, out, _ = run_cli(capsys, "analyze", str(out_dir))
    assert code == 0 and "feed-independent lost motion 30." in out and "B̄ (µm)" in out
