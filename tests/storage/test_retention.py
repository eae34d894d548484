"""Retention of raw runs: the newest stay plain, those around events are never deleted,
older ones are compressed, the oldest beyond the cap are deleted, and every run still
listed reads back exactly."""

import numpy as np
import pytest

from core.dataset import AxisSpec, MachineSpec, Run, RunSpec
from core.errors import InputError
from storage.dataset import append_runs, read_dataset
from storage.retention import RetentionPolicy, apply_retention, folder_bytes

MACHINE = MachineSpec(id="m1", axes={"y": AxisSpec("y", 6.857, 16.0, 10.0, (0.0, 100.0))})


def _run(i: int, n=2000) -> Run:
    t = np.arange(n) * 0.0025
    x = np.sin(t + i) * 50 + 50
    spec = RunSpec(file=f"rt_y_{i:03d}.csv", kind="round_trip", axes=("y",), feed_mm_min=600.0, temperature_c=20.0,
                   extra={"cycle_uuid": f"uuid-{i}"})
    return Run(spec, {"time_s": t, "y_motor_rev": x / 6.857, "y_table_mm": x - 0.05})


@pytest.fixture
def folder(tmp_path):
    for i in range(30):
        append_runs(tmp_path / "ds", MACHINE, [_run(i)])
    return tmp_path / "ds"


def test_retention_keeps_the_newest_and_the_runs_around_events_and_caps_the_rest(folder):
    before = folder_bytes(folder)
    rep = apply_retention(folder, RetentionPolicy(keep_last_runs=5, keep_around_events=1, max_runs=12), ["uuid-5"])
    kept = [r.spec.file for r in read_dataset(folder, load_runs=False).runs]
    expected = [f"rt_y_{i:03d}.csv" for i in (4, 5, 6, *range(21, 30))]
    assert kept == expected and rep.runs == 12 and rep.deleted == 18
    assert rep.deleted_cycle_uuids == tuple(f"uuid-{i}" for i in (*range(0, 4), *range(7, 21)))
    plain = sorted(p.name for p in folder.glob("*.csv"))
    gz = sorted(p.name for p in folder.glob("*.csv.gz"))
    assert plain == [f"rt_y_{i:03d}.csv" for i in range(25, 30)]
    assert gz == [f"rt_y_{i:03d}.csv.gz" for i in (4, 5, 6, 21, 22, 23, 24)] and rep.compressed == 7
    ds = read_dataset(folder)  # compressed runs read back exactly
    for run in ds.runs:
        i = int(run.spec.file[5:8])
        np.testing.assert_array_equal(run.table_mm("y"), _run(i).columns["y_table_mm"])
    assert rep.bytes_on_disk == folder_bytes(folder) < before / 2


def test_retention_is_idempotent_and_never_deletes_within_the_cap(folder):
    policy = RetentionPolicy(keep_last_runs=10, keep_around_events=0, max_runs=100)
    first = apply_retention(folder, policy)
    again = apply_retention(folder, policy)
    assert first.deleted == 0 and first.compressed == 20 and first.runs == 30
    assert again.deleted == 0 and again.compressed == 0 and len(read_dataset(folder).runs) == 30


def test_a_policy_that_contradicts_itself_is_refused_naming_the_option():
    with pytest.raises(InputError, match="max_runs"):
        RetentionPolicy(keep_last_runs=100, max_runs=10)


def test_nothing_is_deleted_when_the_cycles_cannot_be_marked_first(folder):
    class Down(Exception):
        pass

    def refuse(uuids):
        assert uuids == tuple(f"uuid-{i}" for i in range(0, 18))  # told before any file goes
        raise Down("database is locked")

    policy = RetentionPolicy(keep_last_runs=5, keep_around_events=0, max_runs=12)
    files = sorted(p.name for p in folder.iterdir())
    with pytest.raises(Down):
        apply_retention(folder, policy, before_delete=refuse)
    assert len(read_dataset(folder, load_runs=False).runs) == 30 and sorted(p.name for p in folder.iterdir()) == files
    marked = []
    rep = apply_retention(folder, policy, before_delete=marked.extend)
    assert rep.deleted == 18 and tuple(marked) == rep.deleted_cycle_uuids
