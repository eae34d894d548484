"""`mebm circle measure|import|analyze` on the LinuxCNC simulated machine (full-closed, P only,
1 µm scales, the rig's 120 µm backlash): one LinuxCNC start for the module.

mebm measures a circle (R 20 mm, 2000 mm/min, both directions) from the encoders, as a
subprocess, into a dataset folder beside a round trip of X it measured; the same circle is
then written as a ballbar exports it (angle and radial deviation, both directions, in the
layouts of examples/circle-profiles/) and as a trace tool exports the positions of a
second recording, and each imports in one command with the same figures as the encoder
measurement of the same data. Bad files are refused naming what to fix, and nothing is
written then. `mebm circle analyze` of the folder compares the spikes with Eq. 8 at the
round trip's b̄ and decides on a task at the test's radius and feed.
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from acquisition.circle import CircleProgram, circle_gcode, data_arc
from acquisition.linuxcnc.contour import record_contour
from acquisition.linuxcnc.sim import SimSettings
from core.circle import CircularTest, analyze, from_json, pass_from_positions
from tests.acquisition.linuxcnc.rig import AXIS, BACKLASH_UM, running_sim

ROOT = Path(__file__).resolve().parents[2]
PROFILES = ROOT / "examples" / "circle-profiles"
RADIUS_MM, FEED_MM_MIN = 20.0, 2000.0
K_PER_S = AXIS.position_gain_per_s


def mebm(*args: str, check: bool = True) -> subprocess.CompletedProcess:
    done = subprocess.run([sys.executable, "-m", "api.cli", *args], cwd=ROOT, capture_output=True, text=True,
                          timeout=120)
    if check:
        assert done.returncode == 0, done.stderr
    return done


@pytest.fixture(scope="module")
def machine(tmp_path_factory):
    """The dataset folder (a round trip of X, the circle measured by mebm) and two raw
    recordings of the same circle program (for the trace tool's export)."""
    folder = tmp_path_factory.mktemp("circle") / "ds"
    settings = SimSettings(backlash_um=BACKLASH_UM, loop="full", p_gain_per_s=K_PER_S, scale_resolution_um=1.0)
    with running_sim(settings) as sim:
        mebm("measure", "--controller", sim.url + "&trigger=active", "--axis", "x", "--travel-mm", "0", "12",
             "--feed-mm-min", "1200", "--transmission-mm-per-rev", str(AXIS.transmission_mm_per_rev),
             "--position-gain-per-s", str(K_PER_S), "--out", str(folder))
        url = f"linuxcnc://127.0.0.1:{sim.settings.port}?sampler=2"
        measured = mebm("circle", "measure", "--url", url, "--radius-mm", str(RADIUS_MM), "--feed-mm-min",
                        str(FEED_MM_MIN), "--resolution-um", "1", "--out", str(folder), "--json")
        raw = {}
        for d in ("ccw", "cw"):
            program = sim.run_dir / f"{d}.ngc"
            program.write_text(circle_gcode(CircleProgram(RADIUS_MM, FEED_MM_MIN), d))
            program.chmod(0o644)
            raw[d] = record_contour("127.0.0.1", sim.settings.port, str(program))
    doc = json.loads(measured.stdout)
    return folder, Path(doc["file"]), doc, raw


def figures_of(path: Path) -> dict:
    return json.loads(mebm("circle", "analyze", str(path), "--json").stdout)["figures"]


def assert_same_figures(a: dict, b: dict, tol_um: float) -> None:
    for key in ("circular_deviation_um", "circular_deviation_mz_um", "hysteresis_um", "radial_deviation_max_um",
                "radial_deviation_min_um", "mean_radius_deviation_um"):
        assert b[key] == pytest.approx(a[key], abs=tol_um), key
    assert len(a["spikes"]) == len(b["spikes"]) == 8
    for s, t in zip(a["spikes"], b["spikes"]):
        assert (s["axis"], s["direction"], s["quadrant_deg"]) == (t["axis"], t["direction"], t["quadrant_deg"])
        assert t["height_um"] == pytest.approx(s["height_um"], abs=tol_um), (s, t)


def write_direction_column(path: Path, test: CircularTest, *, drop=None, cell=None) -> Path:
    """The test as ballbar-direction-column.toml reads it; ``drop``: a direction left out;
    ``cell``: (row, text) written over one deviation."""
    lines = ["Angle (deg),Deviation (um),Direction"]
    for p in test.passes:
        if p.direction == drop:
            continue
        lines += [f"{a:.5f},{r:.4f},{p.direction.upper()}" for a, r in zip(p.angle_deg, p.radial_um)]
    if cell is not None:
        row, text = cell
        parts = lines[row].split(",")
        lines[row] = ",".join([parts[0], text, parts[2]])
    path.write_text("\n".join(lines) + "\n", encoding="utf-8")
    return path


def write_two_groups(path: Path, test: CircularTest) -> Path:
    """The test as ballbar-two-groups-decimal-comma.toml reads it: cp1252, ';', decimal
    commas, a preamble, the deviation in mm, the shorter direction ending in blank cells."""
    ccw, cw = test.pass_of("ccw"), test.pass_of("cw")
    n = max(ccw.angle_deg.size, cw.angle_deg.size)

    def cells(p, i):
        if i >= p.angle_deg.size:
            return ["", ""]
        return [f"{p.angle_deg[i]:.5f}".replace(".", ","), f"{p.radial_um[i] / 1000:.7f}".replace(".", ",")]

    lines = ["Kreisformtest nach ISO 230-4", "Maschine: Fräszentrum 3, Ebene XY", "Radius 20 mm, Vorschub 2000 mm/min",
             "Winkel GUZ [°];Abweichung GUZ [mm];Winkel UZ [°];Abweichung UZ [mm]"]
    lines += [";".join(cells(ccw, i) + cells(cw, i)) for i in range(n)]
    path.write_text("\r\n".join(lines) + "\r\n", encoding="cp1252")
    return path


def import_circle(file: Path, profile: str, out: Path, *extra: str, check: bool = True):
    return mebm("circle", "import", str(file), "--profile", str(PROFILES / profile), "--radius-mm", str(RADIUS_MM),
                "--feed-mm-min", str(FEED_MM_MIN), "--out", str(out), *extra, check=check)


def test_the_measured_circle_is_in_the_folder_with_both_directions(machine):
    folder, file, doc, _ = machine
    assert file.parent == folder / "circles" and file.is_file()
    test = from_json(json.loads(file.read_text()))
    assert test.directions == ("ccw", "cw") and test.source.startswith("measured: linuxcnc://")
    assert len(doc["figures"]["spikes"]) == 8


@pytest.mark.parametrize("layout", ["direction-column", "two-groups"])
def test_a_ballbar_export_of_the_same_circle_imports_in_one_command_with_the_same_figures(machine, tmp_path, layout):
    _, file, _, _ = machine
    test = from_json(json.loads(file.read_text()))
    if layout == "direction-column":
        export, profile = write_direction_column(tmp_path / "ballbar.csv", test), "ballbar-direction-column.toml"
    else:
        export, profile = write_two_groups(tmp_path / "Kreisform.csv", test), "ballbar-two-groups-decimal-comma.toml"
    out = tmp_path / "imported.json"
    done = import_circle(export, profile, out)
    assert f"-> {out}" in done.stdout and "circular deviation G" in done.stdout
    imported = from_json(json.loads(out.read_text()))
    assert imported.instrument.kind == "ballbar" and imported.source == f"imported: {export.name}"
    # the export rounds the deviation to 0.1 nm: the figures agree to far below a µm
    assert_same_figures(analyze(test).to_dict(), figures_of(out), tol_um=0.01)


def test_a_trace_tool_s_positions_import_with_the_figures_of_the_encoder_measurement(machine, tmp_path):
    *_, raw = machine
    program = CircleProgram(RADIUS_MM, FEED_MM_MIN)
    lines = ["Time [ms]\tX scale [mm]\tY scale [mm]"]
    t0 = 0.0
    passes = []
    for d, rec in raw.items():
        lines += [f"{(t0 + t) * 1e3:.3f}\t{x:.4f}\t{y:.4f}" for t, x, y in zip(rec.time_s, *rec.table_mm)]
        t0 += float(rec.time_s[-1]) + 1.0
        arc = data_arc(rec.command_mm, rec.table_mm, program, d)
        passes.append(pass_from_positions(arc.first_mm, arc.second_mm, radius_mm=RADIUS_MM, centre_mm=arc.centre_mm,
                                          direction=d))
    trace = tmp_path / "trace.txt"
    trace.write_text("\n".join(lines) + "\n")
    out = tmp_path / "trace.json"
    import_circle(trace, "trace-positions-tab.toml", out, "--centre-mm", "0", "0")
    encoders = analyze(CircularTest(RADIUS_MM, FEED_MM_MIN, ("x", "y"), tuple(passes),
                                    from_json(json.loads(out.read_text())).instrument)).to_dict()
    # the import finds the arc from the scales' angle, the measurement from the command's:
    # the same 360° within the loop's lag, so the same spikes and G
    assert_same_figures(encoders, figures_of(out), tol_um=0.5)


def test_analyze_of_the_folder_compares_with_eq_8_at_the_round_trip_s_backlash_and_decides(machine):
    folder, *_ = machine
    doc = json.loads(mebm("circle", "analyze", str(folder), "--json", "--task",
                          f"circle:radius_mm={RADIUS_MM},feed_mm_min={FEED_MM_MIN},tolerance_um=150").stdout)
    (entry,) = doc
    assert {a["axis"] for a in entry["agreement"]} == {"x"}  # the folder holds a round trip of X only
    (ag,) = entry["agreement"]
    assert ag["verdict"] == "agree" and abs(ag["normalised_error"]) <= 1.0, ag
    assert abs(ag["backlash_um"] - BACKLASH_UM) <= 1.0 and ag["backlash_from"].startswith("round trip ")
    assert any("axis y: not compared" in n for n in entry["notes"])
    (decision,) = entry["decision"]
    assert decision["state"] == "OK" and decision["axis"] == "x"
    assert decision["error_um"] == max(s["height_um"] for s in entry["figures"]["spikes"] if s["axis"] == "x")


@pytest.mark.parametrize("case, message", [
    ("nan", "line 41, column 'Deviation (um)': 'nan' is not a finite number"),
    ("missing-direction", "no cw samples: column 'Direction' holds only ['CCW']"),
    ("wrong-unit", "columns.deviation.unit"),
    ("partial-arc", "do not cover the full circle"),
])
def test_a_bad_export_is_refused_naming_what_to_fix_and_nothing_is_written(machine, tmp_path, case, message):
    _, file, _, _ = machine
    test = from_json(json.loads(file.read_text()))
    export = tmp_path / "bad.csv"
    extra: tuple[str, ...] = ()
    if case == "nan":
        write_direction_column(export, test, cell=(40, "nan"))
    elif case == "missing-direction":
        write_direction_column(export, test, drop="cw")
    elif case == "wrong-unit":  # a file in µm, read as mm
        text = (PROFILES / "ballbar-direction-column.toml").read_text().replace('unit = "um"', 'unit = "mm"')
        profile = tmp_path / "mm.toml"
        profile.write_text(text)
        write_direction_column(export, test)
        out = tmp_path / "out.json"
        done = mebm("circle", "import", str(export), "--profile", str(profile), "--radius-mm", str(RADIUS_MM),
                    "--feed-mm-min", str(FEED_MM_MIN), "--out", str(out), check=False)
        assert done.returncode == 1 and message in done.stderr and "'um'" in done.stderr, done.stderr
        assert not out.exists()
        return
    else:  # the export stops at 200°: two quadrants incomplete
        lines = ["Angle (deg),Deviation (um),Direction"]
        for p in test.passes:
            keep = np.unwrap(np.deg2rad(p.angle_deg))
            keep = np.abs(np.rad2deg(keep - keep[0])) < 200.0
            lines += [f"{a:.5f},{r:.4f},{p.direction.upper()}" for a, r in zip(p.angle_deg[keep], p.radial_um[keep])]
        export.write_text("\n".join(lines) + "\n")
    out = tmp_path / "out.json"
    done = import_circle(export, "ballbar-direction-column.toml", out, *extra, check=False)
    assert done.returncode == 1, done.stdout
    assert message in done.stderr and str(export) in done.stderr, done.stderr
    assert "Traceback" not in done.stderr
    assert not out.exists()
    if case == "missing-direction":
        assert "--directions ccw" in done.stderr  # the option that imports what there is
        assert import_circle(export, "ballbar-direction-column.toml", out, "--directions", "ccw").returncode == 0


def test_the_tour_s_circular_test_on_the_simulated_machine_agrees_with_eq_8_and_is_never_overwritten(tmp_path):
    command = ["circle", "measure", "--url", "sim:?backlash_um=120&gain_per_s=30", "--radius-mm", "50",
               "--feed-mm-min", "2000"]
    assert "mebm " + " ".join(command[:3]) + " 'sim:?backlash_um=120&gain_per_s=30' --radius-mm 50 --feed-mm-min 2000" \
        in (ROOT / "README.md").read_text()  # the tour's command
    out = tmp_path / "circle.json"
    done = mebm(*command, "--out", str(out))
    assert "spike ccw at   0° (axis x reverses)" in done.stdout and "circular hysteresis H" in done.stdout

    def verdicts(backlash_um: str) -> list[str]:
        doc = json.loads(mebm("circle", "analyze", str(out), "--backlash-um", backlash_um, "--backlash-u-um", "0.5",
                              "--gain-per-s", "30", "--json").stdout)
        return [a["verdict"] for a in doc["agreement"]]

    assert verdicts("120") == ["agree", "agree"]
    assert verdicts("60") == ["larger", "larger"]  # half the play explains smaller spikes than measured
    again = mebm(*command, "--out", str(out), check=False)
    assert again.returncode == 1 and "nothing stored is overwritten" in again.stderr
