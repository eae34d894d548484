"""Dataset folders: exact round trips, and clear errors naming the file and row."""

import json

import numpy as np
import pytest

from core.dataset import AxisSpec, Dataset, MachineSpec, Run, RunSpec
from core.errors import DatasetError
from core.sim import AxisModel, round_trip, simulate
from storage.dataset import append_runs, next_run_name, read_dataset, write_dataset

MACHINE = MachineSpec(id="m1", axes={"y": AxisSpec("y", 6.857, 16.0, 10.0, (0.0, 100.0))})


def small_run(file="rt_y_00.csv", n=5):
    t = np.arange(n) * 0.001
    cols = {"time_s": t, "y_command_mm": t * 10, "y_motor_rev": t * 10 / 6.857, "y_table_mm": t * 10 - 0.05}
    spec = RunSpec(file=file, kind="round_trip", axes=("y",), feed_mm_min=600.0, temperature_c=21.5,
                   extra={"note": "kept"})  # fmt: skip
    return Run(spec, cols)


@pytest.fixture
def folder(tmp_path):
    write_dataset(tmp_path / "ds", Dataset(MACHINE, (small_run(),), extra={"source": "test"}))
    return tmp_path / "ds"


def test_write_then_read_is_exact_and_keeps_unknown_fields(folder):
    ds = read_dataset(folder)
    assert ds.machine == MACHINE and ds.extra == {"source": "test"}
    (run,) = ds.runs
    assert run.spec == small_run().spec and run.spec.extra == {"note": "kept"}
    for name, col in small_run().columns.items():
        assert np.array_equal(run.columns[name], col)


def test_a_simulated_trace_round_trips_through_a_folder(tmp_path):
    trace = simulate({"y": AxisModel(backlash_um=30.0)}, round_trip(0.0, 10.0, 1200.0, dwell_s=0.2), rate_hz=200.0)
    run = trace.to_run("rt_y_00.csv", split="test", utility_day=12.0)
    append_runs(tmp_path / "ds", MachineSpec("sim", {"y": AxisModel().to_axis_spec((0.0, 10.0))}), [run])
    back = read_dataset(tmp_path / "ds").runs[0]
    assert back.spec.split == "test" and back.spec.utility_day == 12.0 and back.spec.extra["simulated"] is True
    assert set(back.columns) == {"time_s", "y_command_mm", "y_motor_rev", "y_table_mm"}
    assert np.array_equal(back.table_mm("y"), trace.table_mm["y"])
    assert next_run_name(tmp_path / "ds", "rt_y") == "rt_y_01.csv"


def _rewrite_csv(folder, edit):
    path = folder / "rt_y_00.csv"
    lines = path.read_text().splitlines()
    path.write_text("\n".join(edit(lines)) + "\n")


def _error(folder):
    with pytest.raises(DatasetError) as exc:
        read_dataset(folder)
    return str(exc.value)


def test_missing_column_names_the_file_and_the_column(folder):
    def drop_table(lines):
        return [",".join(c for i, c in enumerate(line.split(",")) if i != 3) for line in lines]

    _rewrite_csv(folder, drop_table)
    msg = _error(folder)
    assert "rt_y_00.csv" in msg and "missing column 'y_table_mm'" in msg


def test_axis_not_in_machine_names_the_run_and_the_axes(folder):
    doc = json.loads((folder / "dataset.json").read_text())
    doc["runs"][0]["axes"] = ["z"]
    (folder / "dataset.json").write_text(json.dumps(doc))
    msg = _error(folder)
    assert "dataset.json" in msg and "'rt_y_00.csv'" in msg and "axis 'z'" in msg and "['y']" in msg


def test_non_increasing_time_names_the_file_and_row(folder):
    def repeat_time(lines):
        cells = lines[3].split(",")
        cells[0] = lines[2].split(",")[0]
        return lines[:3] + [",".join(cells)] + lines[4:]

    _rewrite_csv(folder, repeat_time)
    msg = _error(folder)
    assert msg.endswith("rt_y_00.csv, row 3: time_s not strictly increasing (0.001 s then 0.001 s)")


def test_nan_names_the_file_row_and_column(folder):
    def nan_motor(lines):
        cells = lines[4].split(",")
        cells[2] = "nan"
        return lines[:4] + [",".join(cells)] + lines[5:]

    _rewrite_csv(folder, nan_motor)
    msg = _error(folder)
    assert msg.endswith("rt_y_00.csv, row 4: column y_motor_rev is not a number (nan): "
                        "the sample was not read; remove the row or measure again")
    assert "np.float64" not in msg


def test_text_in_a_number_cell_names_the_file_and_row(folder):
    _rewrite_csv(folder, lambda lines: lines[:2] + ["0.001,abc,0,0"] + lines[3:])
    msg = _error(folder)
    assert "rt_y_00.csv, row 2" in msg and "'abc'" in msg


def test_file_missing_from_the_folder_is_named(folder):
    (folder / "rt_y_00.csv").unlink()
    msg = _error(folder)
    assert "rt_y_00.csv" in msg and "missing" in msg


def test_missing_dataset_json_and_wrong_format_are_named(tmp_path, folder):
    (tmp_path / "empty").mkdir()
    assert "dataset.json not found" in _error(tmp_path / "empty")
    doc = json.loads((folder / "dataset.json").read_text())
    doc["format"] = "other/2"
    (folder / "dataset.json").write_text(json.dumps(doc))
    assert "'other/2'" in _error(folder)


def test_a_truncated_dataset_json_names_the_file_the_position_and_what_to_do(folder):
    text = (folder / "dataset.json").read_text()
    quote = text.index('"kind"')
    (folder / "dataset.json").write_text(text[:quote + 3])  # cut inside a string: it is never closed
    line = text[:quote].count("\n") + 1
    col = quote - text[:quote].rindex("\n")  # the string's opening quote, 1-based
    with pytest.raises(DatasetError) as ei:
        read_dataset(folder)
    assert str(ei.value) == (f"{folder / 'dataset.json'}: Unterminated string starting at line {line}, column {col}: "
                             "the file is cut short or not JSON: restore it from a copy or write it again")
    assert "at at" not in str(ei.value)


def test_appending_a_listed_file_or_a_different_axis_is_refused(folder):
    with pytest.raises(DatasetError, match="already in the dataset"):
        append_runs(folder, MACHINE, [small_run()])
    other = MachineSpec("m1", {"y": AxisSpec("y", 5.0, 16.0, 10.0, (0.0, 100.0))})
    with pytest.raises(DatasetError, match="differs"):
        append_runs(folder, other, [small_run("rt_y_01.csv")])


def test_a_different_axis_is_named_field_by_field_and_replace_axes_replaces_it(folder):
    other = MachineSpec("m1", {"y": AxisSpec("y", 5.0, None, 10.0, (0.0, 100.0))})
    with pytest.raises(DatasetError) as err:
        append_runs(folder, other, [small_run("rt_y_01.csv")])
    text = str(err.value)
    assert ("transmission ratio k_a (transmission_mm_per_rev): 6.857 mm/rev stored, 5 mm/rev given; "
            "screw lead (screw_lead_mm): 16 mm stored, not known given") in text
    assert "AxisSpec" not in text and "position_gain" not in text  # the fields that agree are not listed
    append_runs(folder, other, [small_run("rt_y_01.csv")], replace_axes=("y",))
    ds = read_dataset(folder)
    assert ds.machine.axes["y"] == other.axes["y"] and [r.spec.file for r in ds.runs] == ["rt_y_00.csv", "rt_y_01.csv"]


def test_an_axis_without_position_gain_is_written_without_it_and_read_as_not_known(tmp_path):
    machine = MachineSpec("m1", {"y": AxisSpec("y", 6.857, None, None, (0.0, 100.0))})
    write_dataset(tmp_path / "ds", Dataset(machine, (small_run(),)))
    axis = json.loads((tmp_path / "ds" / "dataset.json").read_text())["machine"]["axes"]["y"]
    assert axis == {"transmission_mm_per_rev": 6.857, "travel_mm": [0.0, 100.0]}
    assert read_dataset(tmp_path / "ds").machine.axes["y"].position_gain_per_s is None
    doc = json.loads((tmp_path / "ds" / "dataset.json").read_text())
    doc["machine"]["axes"]["y"]["position_gain_per_s"] = None  # null reads as not known too
    (tmp_path / "ds" / "dataset.json").write_text(json.dumps(doc))
    assert read_dataset(tmp_path / "ds").machine.axes["y"].position_gain_per_s is None
    with pytest.raises(DatasetError, match=r"position_gain_per_s \(=0\) must be a number > 0"):
        AxisSpec("y", 6.857, None, 0.0, (0.0, 100.0))


def test_concurrent_writers_under_the_folder_lock_lose_no_run_and_reuse_no_name(tmp_path):
    import threading

    from storage.dataset import dataset_lock

    folder = tmp_path / "ds"
    start = threading.Barrier(8)
    errors = []

    def writer():
        start.wait()
        for _ in range(5):
            try:
                with dataset_lock(folder):
                    name = next_run_name(folder, "rt_y_20260101T000000")
                    append_runs(folder, MACHINE, [small_run(name)])
            except Exception as exc:  # noqa: BLE001 - collected and asserted below
                errors.append(exc)

    threads = [threading.Thread(target=writer) for _ in range(8)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert errors == []
    ds = read_dataset(folder)
    names = [r.spec.file for r in ds.runs]
    assert len(names) == 40 and len(set(names)) == 40
    assert sorted(p.name for p in folder.glob("*.csv")) == sorted(names)


def test_a_name_listed_in_dataset_json_is_not_reused_even_when_its_file_is_gone(folder):
    (folder / "rt_y_00.csv").rename(folder / "rt_y_00.csv.gz")  # e.g. compressed by retention
    assert next_run_name(folder, "rt_y") == "rt_y_01.csv"
    (folder / "rt_y_00.csv.gz").unlink()
    assert next_run_name(folder, "rt_y") == "rt_y_01.csv"


def test_dataset_json_is_replaced_atomically_and_leaves_no_temporary_file(folder):
    append_runs(folder, MACHINE, [small_run("rt_y_01.csv")])
    assert sorted(p.name for p in folder.iterdir() if p.name.startswith(".") and p.name != ".dataset.lock") == []
