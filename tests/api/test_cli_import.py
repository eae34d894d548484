"""`mebm import`: a controller's scope trace (CSV) into a dataset, as a user calls it.

A twin round trip is written as a trace tool would export it (a preamble, ';' between
fields, decimal commas, time in ms, the motor in degrees, the scale in µm, the command in
mm, the temperature in K); imported with a profile, it analyses as the original run does.
Bad files and bad profiles end in one message naming the line and the column, or the field.
"""

import json
import re

import numpy as np
import pytest

from api.cli.main import main
from core.sim import AxisModel, Encoders, round_trip, simulate

KA = 6.857
PROFILE = """
format = "mebm-trace-profile/1"

[machine]
id = "vmc-850"
[machine.axes.y]
transmission_mm_per_rev = 6.857
screw_lead_mm = 16.0
position_gain_per_s = 10.0
travel_mm = [60.0, 540.0]

[csv]
delimiter = ";"
decimal = ","
header_line = 4

[columns]
time_s = {{name = "Zeit [ms]", unit = "ms"}}
y_motor_rev = {{name = "Motor [deg]", unit = "deg"}}
y_table_mm = {{name = "Maßstab [µm]", unit = "{table_unit}"}}
y_command_mm = {{name = "Soll [mm]", unit = "mm"}}
temperature_c = {{name = "Temp [K]", unit = "K"}}

[run]
kind = "round_trip"
{feed}
"""


@pytest.fixture(scope="module")
def twin_run():
    axis = AxisModel(name="y", transmission_mm_per_rev=KA, screw_lead_mm=16.0, position_gain_per_s=10.0,
                     backlash_um=180.0, encoders=Encoders(table_noise_um=0.2, motor_noise_um=0.2))
    tr = simulate({"y": axis}, round_trip(50.0, 550.0, 3000.0, 800.0, 0.5, axis="y"), temperature_c=21.4,
                  rate_hz=500.0, rng=np.random.default_rng(5))
    return tr.to_run("rt_y_00.csv")


def _vendor_csv(path, run, *, bad_cell_at=None, swap_times_at=None):
    t_ms = run.time_s * 1e3 + 123456.0  # the controller's clock, not zero
    if swap_times_at is not None:
        t_ms[swap_times_at] = t_ms[swap_times_at - 1]
    lines = ["Trace export;Achse Y", "Recorded 2026-11-24 10:00", "", "Zeit [ms];Motor [deg];Maßstab [µm];Soll [mm];Temp [K]"]
    for i, (t, m, x, c) in enumerate(zip(t_ms, run.motor_rev("y"), run.table_mm("y"), run.command_mm("y"))):
        table = "n/a" if i == bad_cell_at else f"{x * 1e3:.5f}".replace(".", ",")
        lines.append(";".join([f"{t:.4f}".replace(".", ","), f"{m * 360.0:.7f}".replace(".", ","), table,
                               f"{c:.7f}".replace(".", ","), "294,55"]))
    path.write_text("\n".join(lines) + "\n\n", encoding="utf-8")
    return path


def _profile(tmp_path, table_unit="um", feed='feed_mm_min = 3000'):
    p = tmp_path / "profile.toml"
    p.write_text(PROFILE.format(table_unit=table_unit, feed=feed), encoding="utf-8")
    return p


def _cli(capsys, *argv):
    code = main([str(a) for a in argv])
    out, err = capsys.readouterr()
    return code, out, err


def test_a_vendor_trace_imports_and_analyses_as_the_original_run(tmp_path, capsys, twin_run):
    from core.dataset import Dataset, MachineSpec
    from storage.dataset import read_dataset, write_dataset

    spec = AxisModel(name="y", transmission_mm_per_rev=KA, screw_lead_mm=16.0, position_gain_per_s=10.0,
                     backlash_um=0.0).to_axis_spec((60.0, 540.0))
    orig = write_dataset(tmp_path / "orig", Dataset(MachineSpec("vmc-850", {"y": spec}), (twin_run,)))
    trace = _vendor_csv(tmp_path / "Trace Y 01.csv", twin_run)
    out = tmp_path / "imported"
    code, text, err = _cli(capsys, "import", trace, "--profile", _profile(tmp_path), "--out", out)
    assert code == 0, err
    assert "Trace_Y_01_00.csv" in text and f"{len(twin_run)} samples" in text and "mebm analyze" in text
    ds = read_dataset(out)
    (run,) = ds.runs
    assert run.spec.temperature_c == pytest.approx(21.4, abs=1e-9)  # the mean of the K column
    assert run.spec.feed_mm_min == 3000 and run.spec.extra["imported_from"] == "Trace Y 01.csv"
    assert run.time_s[0] == 0.0 and np.allclose(run.time_s, twin_run.time_s, atol=1e-7)
    assert np.allclose(run.command_mm("y"), twin_run.command_mm("y"), atol=1e-6)
    results = []
    for folder in (orig, out):
        code, text, err = _cli(capsys, "analyze", folder, "--json")
        assert code == 0, err
        results.append(json.loads(text)[0])
    a, b = results
    assert b["backlash_mean_um"] == pytest.approx(a["backlash_mean_um"], abs=0.01)
    assert abs(b["backlash_mean_um"] - 180.0) < 2.0
    for key in ("e_p_um", "v_u_um", "v_300_um", "v_2pi_um"):
        assert b["strokes"]["positive"][key] == pytest.approx(a["strokes"]["positive"][key], abs=0.01)
    # a second trace into the same dataset gets a name of its own; nothing is overwritten
    code, text, _ = _cli(capsys, "import", trace, "--profile", _profile(tmp_path), "--out", out, "--split", "test")
    assert code == 0 and "Trace_Y_01_01.csv" in text
    assert [r.spec.file for r in read_dataset(out).runs] == ["Trace_Y_01_00.csv", "Trace_Y_01_01.csv"]


@pytest.mark.parametrize("case, expected", [
    ("bad_cell", "line 15, column 'Maßstab [µm]': 'n/a' is not a finite number"),
    ("time_back", "line 26: time does not increase"),
    ("unit", "columns.y_table_mm.unit (='furlong') must be one of"),
    ("no_feed", "stroke has no stretch of constant speed of 0.1 s or more to read the feed from (its top speed "
                "is 2778 mm/min); give the programmed feed with --feed-mm-min or the profile's run.feed_mm_min"),
    ("column", "no column 'Maßstab [µm]' (for y_table_mm); the header has"),
])
def test_a_bad_trace_or_profile_is_refused_naming_line_column_or_field(tmp_path, capsys, twin_run, case, expected):
    short = twin_run.__class__(twin_run.spec, {k: v[:400] for k, v in twin_run.columns.items()})
    trace = _vendor_csv(tmp_path / "t.csv", short, bad_cell_at=10 if case == "bad_cell" else None,
                        swap_times_at=21 if case == "time_back" else None)
    if case == "column":
        trace.write_text(trace.read_text(encoding="utf-8").replace("Maßstab [µm]", "Scale"), encoding="utf-8")
    prof = _profile(tmp_path, table_unit="furlong" if case == "unit" else "um",
                    feed="" if case == "no_feed" else "feed_mm_min = 3000")
    code, _, err = _cli(capsys, "import", trace, "--profile", prof, "--out", tmp_path / "ds")
    assert code != 0
    assert expected in err, err
    assert err.count("\n") == 1 and err.endswith("\n")  # one line, once
    assert not (tmp_path / "ds" / "dataset.json").exists()  # nothing half-written


def test_the_shipped_counts_profile_reads_raw_encoder_counts(tmp_path, capsys, twin_run):
    """examples/trace-profiles/counts-comma-separated.toml: 2^20 counts/rev, 0.05 µm counts
    with the scale's zero 250 mm off, time in µs."""
    from pathlib import Path

    from storage.dataset import read_dataset

    root = Path(__file__).resolve().parents[2]
    motor = np.round(twin_run.motor_rev("y") * 2**20)
    table = np.round((twin_run.table_mm("y") - 250.0) * 1e3 / 0.05)
    rows = ["t_us,enc1_counts,enc2_counts"] + [f"{t * 1e6:.0f},{m:.0f},{x:.0f}"
                                               for t, m, x in zip(twin_run.time_s, motor, table)]  # fmt: skip
    trace = tmp_path / "x.csv"
    trace.write_text("\n".join(rows) + "\n", encoding="utf-8")
    code, _, err = _cli(capsys, "import", trace, "--profile", root / "examples/trace-profiles/counts-comma-separated.toml",
                        "--out", tmp_path / "ds")  # fmt: skip
    assert code == 0, err
    (run,) = read_dataset(tmp_path / "ds").runs
    assert run.spec.axes == ("x",) and run.spec.extra["temperature_measured"] is False  # no column, none given
    assert run.spec.extra["feed_from_data"] is True and run.spec.feed_mm_min == pytest.approx(3000.0, rel=2e-3)
    assert np.allclose(run.table_mm("x"), twin_run.table_mm("y"), atol=0.05e-3)  # one count
    assert np.allclose(run.motor_rev("x"), twin_run.motor_rev("y"), atol=1.0 / 2**20)
    # the other shipped profile parses too
    from api.cli.import_trace import load_trace_profile
    from acquisition.trace_import import parse_profile

    doc = load_trace_profile(root / "examples/trace-profiles/scope-semicolon-decimal-comma.toml")
    assert {c.target for c in parse_profile(doc, ("y",), {"y": KA}).columns} >= {"time_s", "y_motor_rev", "y_table_mm"}


def test_a_trace_without_overtravel_or_screw_lead_imports_and_analyses_in_one_command(tmp_path, capsys, twin_run):
    # the profile knows neither the useful travel nor the screw lead; the trace reverses at
    # 50 and 550 mm with no overtravel beyond what it measures
    prof = _profile(tmp_path)
    prof.write_text(prof.read_text(encoding="utf-8").replace("screw_lead_mm = 16.0\n", "")
                    .replace("travel_mm = [60.0, 540.0]\n", ""), encoding="utf-8")
    out = tmp_path / "ds"
    code, text, err = _cli(capsys, "import", _vendor_csv(tmp_path / "t.csv", twin_run), "--profile", prof, "--out", out)
    assert code == 0, err
    m = re.search(r"useful travel ([\d.]+)\.\.([\d.]+) mm \([\d.]+ mm\): what both strokes cover outside the "
                  r"reversal transients", text)
    assert m and 50.0 < float(m[1]) < 60.0 and 540.0 < float(m[2]) < 550.0, text
    b = float(re.search(r"mean backlash b̄ ([\d.]+) ±", text)[1])
    assert abs(b - 180.0) < 2.0
    assert "v_300 (travel variation within 300 mm, positive stroke): " in text
    assert "v_2π (travel variation within one revolution (2π rad), positive stroke): not computed" in text
    assert ("needs the screw lead: v_2π (its window is one lead; give --screw-lead-mm or the profile's "
            "machine.axes.y.screw_lead_mm)") in text
    axis = json.loads((out / "dataset.json").read_text())["machine"]["axes"]["y"]
    assert "screw_lead_mm" not in axis and axis["travel_mm"] == [float(m[1]), float(m[2])]
    code, text, err = _cli(capsys, "analyze", out, "--json")
    assert code == 0, err
    (r,) = json.loads(text)
    assert r["v_2pi_um"] is None and r["v_300_um"] > 0 and r["backlash_mean_um"] == pytest.approx(b, abs=0.01)
    assert r["needs_screw_lead"]["v_2pi"].endswith("its window is one screw lead; give the axis' screw_lead_mm")


def test_a_profile_axis_without_travel_that_the_run_does_not_move_is_not_written(tmp_path, capsys, twin_run):
    # x has no travel_mm and the trace is of y: x's travel is unknown, so dataset.json
    # holds y only, rather than a made-up travel for x
    prof = _profile(tmp_path)
    text = prof.read_text(encoding="utf-8").replace(
        "[csv]", "[machine.axes.x]\ntransmission_mm_per_rev = 10.0\nposition_gain_per_s = 10.0\n\n[csv]")
    prof.write_text(text.replace('kind = "round_trip"', 'kind = "round_trip"\naxes = ["y"]'), encoding="utf-8")
    out = tmp_path / "ds"
    code, _, err = _cli(capsys, "import", _vendor_csv(tmp_path / "t.csv", twin_run), "--profile", prof, "--out", out)
    assert code == 0, err
    axes = json.loads((out / "dataset.json").read_text())["machine"]["axes"]
    assert sorted(axes) == ["y"] and axes["y"]["travel_mm"] == [60.0, 540.0]
