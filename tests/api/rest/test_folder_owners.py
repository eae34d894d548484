"""Folders that cannot be shared: a dataset folder records the machine and axis it
belongs to, a new database on an old data directory (its ids start at 1 again) never
appends to the old machine's folder, and the gap diagnosis uses only the axis' own runs."""

from __future__ import annotations

import json
import uuid
from dataclasses import replace
from pathlib import Path

import numpy as np
from fastapi.testclient import TestClient

from api.rest import create_app
from api.service.cycles.runner import CycleOutcome
from api.service.gap_jobs import dataset_of
from core.dataset import Dataset, MachineSpec, Run, RunSpec
from storage.dataset import LOCK_FILE, read_dataset, write_dataset, write_run_csv
from storage.db import config_repo, results_repo, session_scope
from tests.api.rest.conftest import FakeRunner, hdr, make_settings
from tests.api.rest.test_gap import get_report
from tests.storage.db import factories as f
from tests.storage.db.backends import truncate_all

OLD_UM, NEW_UM = 180.0, 260.0  # the backlash of the old machine and of the new database's one
NEW_STEP_MM = 0.5  # the new machine's round trips are sampled every 0.5 mm: a tenth of the default's samples


def runs_it_read(folder: str, plan: dict) -> dict:
    """The gap job's work in place of the diagnosis (module level: the spawned worker
    imports it): the runs the job reads, named as the diagnosis names its ``runs_used``.
    What the diagnosis makes of runs is tested in tests/core/gap and test_gap.py."""
    return {"runs_used": [r.spec.file for r in dataset_of(Path(folder), plan["files"]).runs]}


def _axis(svc):
    with session_scope(svc.factory) as s:
        return config_repo.list_axes(s)[0]


def _ok_cycles(svc, axis_id):
    with session_scope(svc.factory) as s:
        return results_repo.list_measurements(s, axis_id, status="ok", limit=500)[1]


def _measure(svc, axis_id, n, runner=None, temperatures=None):
    for i in range(n):
        if runner is not None and temperatures is not None:
            runner.temperature_c = temperatures[i % len(temperatures)]
        svc.scheduler.request(axis_id, "manual")
        assert svc.scheduler.idle(60)


def _keys(svc):
    with session_scope(svc.factory) as s:
        return {role: config_repo.create_key(s, f"k-{role}", role)[1] for role in ("read", "operate")}


def _foreign_runs(n=3, owner=None):
    """A folder as another database's service left it: runs of cycles this one never ran."""
    t, m, x = f.trace(OLD_UM)
    runs = tuple(Run(RunSpec(file=f"rt_y_{i:02d}.csv", kind="round_trip", axes=("y",), feed_mm_min=1000.0,
                             temperature_c=20.0, extra={"cycle_uuid": str(uuid.uuid4()), "axis_id": 1}),
                     {"time_s": t, "y_motor_rev": m, "y_table_mm": x}) for i in range(n))
    return Dataset(MachineSpec("vmc-850", {"y": replace(f.AXIS, name="y")}), runs,
                   {"owner": owner} if owner else {})


def test_a_new_database_on_an_old_data_dir_never_appends_to_the_old_machines_folder(engine, db_url, tmp_path):
    settings = make_settings(db_url, tmp_path)
    old_runner = FakeRunner(backlash_um=OLD_UM)
    app = create_app(settings, runner=old_runner)
    with TestClient(app):
        svc = app.state.service
        old_axis = _axis(svc)
        _measure(svc, old_axis.id, 14)
        folder = svc.executor.dataset_folder(old_axis)
    old_files = sorted(p.name for p in folder.iterdir())
    old_doc = json.loads((folder / "dataset.json").read_text())
    assert old_doc["owner"]["axis_uuid"] == old_axis.uuid and len(old_doc["runs"]) == 14

    truncate_all(engine)  # the database created anew; the data directory stays
    runner = FakeRunner(backlash_um=NEW_UM, step_mm=NEW_STEP_MM)
    app = create_app(settings, runner=runner)
    with TestClient(app) as client:
        svc = app.state.service
        axis = _axis(svc)
        assert (axis.id, axis.machine_id) == (old_axis.id, old_axis.machine_id)  # the same folder name
        assert axis.uuid != old_axis.uuid
        aside = folder.with_name(f"{folder.name}.of-machine-{old_axis.machine_uuid}")
        (line,) = svc.report.folders_moved_aside
        assert folder.name in line and aside.name in line and old_axis.machine_uuid in line
        assert sorted(p.name for p in aside.iterdir()) == old_files  # moved whole, nothing lost
        assert json.loads((aside / "dataset.json").read_text()) == old_doc
        _measure(svc, axis.id, 4, runner, temperatures=(15.0, 20.0, 25.0, 30.0))
        own = _ok_cycles(svc, axis.id)
        ds = read_dataset(folder)
        assert sorted(r.spec.file for r in ds.runs) == sorted(c.run_file for c in own) and len(own) == 4
        assert ds.extra["owner"]["axis_uuid"] == axis.uuid and ds.extra["owner"]["machine_uuid"] == axis.machine_uuid
        for run in ds.runs:  # this machine's data only
            np.testing.assert_allclose(run.table_mm("y"), f.trace(NEW_UM, step_mm=NEW_STEP_MM)[2])
        assert len(read_dataset(aside, load_runs=False).runs) == 14  # and the old folder got none of them

        # the job's runs, read in the diagnosis' worker process: the 4 own runs, none of the 14 old ones
        svc.gap_jobs.compute = runs_it_read
        r = get_report(client, f"/api/v1/axes/{axis.id}/gap", hdr(_keys(svc)["read"]))
        assert r.status_code == 200, r.text
        assert r.json()["runs_used"] == [r.spec.file for r in ds.runs]


def test_a_folder_written_by_this_database_without_an_owner_is_adopted(engine, db_url, tmp_path):
    settings = make_settings(db_url, tmp_path)
    app = create_app(settings, runner=FakeRunner())
    with TestClient(app):
        svc = app.state.service
        axis = _axis(svc)
        _measure(svc, axis.id, 2)
        folder = svc.executor.dataset_folder(axis)
    doc = json.loads((folder / "dataset.json").read_text())
    del doc["owner"]  # as folders were written before owners were recorded
    doc["runs"].append({"file": "imported_00.csv", "kind": "round_trip", "axes": ["y"], "feed_mm_min": 500,
                        "temperature_c": 21.0})  # a run put there by hand (mebm import): no cycle of anyone
    t, m, x = f.trace(200.0)
    write_run_csv(folder / "imported_00.csv", {"time_s": t, "y_motor_rev": m, "y_table_mm": x})
    (folder / "dataset.json").write_text(json.dumps(doc))
    app = create_app(settings, runner=FakeRunner())
    with TestClient(app):
        svc = app.state.service
        assert svc.report.folders_moved_aside == ()
        assert read_dataset(folder, load_runs=False).extra["owner"]["axis_uuid"] == axis.uuid
        _measure(svc, axis.id, 1)
        files = [r.spec.file for r in read_dataset(folder).runs]
    assert len(files) == 4 and "imported_00.csv" in files
    assert not list(folder.parent.glob("*.of-*"))


def test_a_foreign_folder_met_by_a_measurement_is_moved_aside_and_a_new_one_begun(app_env):
    client, svc, keys, axis_id = app_env
    with session_scope(svc.factory) as s:
        axis = config_repo.get_axis(s, axis_id)
    folder = svc.executor.dataset_folder(axis)
    write_dataset(folder, _foreign_runs())  # no owner, runs of cycles this database does not hold
    r = client.get(f"/api/v1/axes/{axis_id}/gap", headers=hdr(keys["read"]))
    assert r.status_code == 409, r.text
    assert "not axis" in r.json()["detail"] and "move it aside" in r.json()["detail"]
    before = sorted(p.name for p in folder.iterdir())
    r = client.post(f"/api/v1/axes/{axis_id}/measurements", headers=hdr(keys["operate"]))
    assert r.status_code in (200, 201, 202), r.text
    assert svc.scheduler.idle(30)
    aside = folder.with_name(f"{folder.name}.of-unknown-database")
    assert sorted(p.name for p in aside.iterdir() if p.name != LOCK_FILE) == before
    (c,) = _ok_cycles(svc, axis_id)
    ds = read_dataset(folder, load_runs=False)
    assert [r.spec.file for r in ds.runs] == [c.run_file] and ds.extra["owner"]["axis_uuid"] == axis.uuid
    assert folder.name + ".of-" not in str(svc.axis_folders(axis))  # retention never sees it


def test_the_gap_refuses_a_folder_that_records_another_owner(app_env):
    client, svc, keys, axis_id = app_env
    with session_scope(svc.factory) as s:
        axis = config_repo.get_axis(s, axis_id)
    other = {"machine_uuid": str(uuid.uuid4()), "axis_uuid": str(uuid.uuid4()), "machine": "vmc-850", "axis": "y"}
    write_dataset(svc.executor.dataset_folder(axis), _foreign_runs(owner=other))
    r = client.get(f"/api/v1/axes/{axis_id}/gap", headers=hdr(keys["read"]))
    assert r.status_code == 409, r.text
    assert other["machine_uuid"] in r.json()["detail"]


class RejectingRunner(FakeRunner):
    """A round trip whose analysis is refused: its trace goes to the ``_rejected`` folder."""

    def __call__(self, axis, url) -> CycleOutcome:
        t, m, x = f.trace(self.backlash_um)
        return CycleOutcome(ok=False, reason="no reversal found", time_s=t, motor_rev=m, table_mm=x,
                            temperature_c=20.0)


def test_old_folders_of_every_kind_are_kept_from_a_new_database(engine, db_url, tmp_path):
    settings = make_settings(db_url, tmp_path)
    app = create_app(settings, runner=FakeRunner(backlash_um=OLD_UM))
    with TestClient(app):
        svc = app.state.service
        old = _axis(svc)
        _measure(svc, old.id, 2)
        svc.executor.runner = RejectingRunner(backlash_um=OLD_UM)
        _measure(svc, old.id, 1)
        folder = svc.executor.dataset_folder(old)
    rejected = folder.with_name(folder.name + "_rejected")
    assert len(read_dataset(rejected, load_runs=False).runs) == 1
    legacy = folder.with_name("vmc-850_y")  # as a version naming folders by names left it
    write_dataset(legacy, read_dataset(folder))
    legacy_doc = (legacy / "dataset.json").read_text()

    truncate_all(engine)
    for _ in range(2):  # the second start knows the axis when it looks at the legacy folder
        app = create_app(settings, runner=FakeRunner(backlash_um=NEW_UM))
        with TestClient(app):
            svc = app.state.service
            report = svc.report
            axis = _axis(svc)
            _measure(svc, axis.id, 1)
        if _ == 0:
            moved = {line.split(" moved aside to ")[1].split(":")[0] for line in report.folders_moved_aside}
            assert moved == {f"{folder.name}.of-machine-{old.machine_uuid}",
                             f"{rejected.name}.of-machine-{old.machine_uuid}"}
    assert (legacy / "dataset.json").read_text() == legacy_doc  # another database's runs: left as they are
    runs = read_dataset(folder, load_runs=False).runs
    assert {r.spec.extra["cycle_uuid"] for r in runs} == {c.uuid for c in _ok_cycles(svc, axis.id)}
    assert len(runs) == 2


def test_the_start_banner_says_which_folder_was_moved_aside_and_where_to_read_what_to_do(tmp_path):
    from api.cli.serve import banner
    from api.service.service import StartReport

    line = "dataset folder machine-1_axis-1 moved aside to machine-1_axis-1.of-machine-abc: it belongs to ..."
    report = StartReport(database="sqlite:///x", replayed=0, interrupted=0, created_axes=(), demo_keys={},
                         simulators={}, bootstrap_admin=None, folders_moved_aside=(line,))
    text = banner(make_settings("sqlite:///x", tmp_path), report, "http://127.0.0.1:1")
    shown = [ln for ln in text.splitlines() if ln.startswith(line)]
    assert len(shown) == 1 and "nothing deleted" in shown[0] and "Dataset folders and their owner" in shown[0]
    quiet = banner(make_settings("sqlite:///x", tmp_path), replace(report, folders_moved_aside=()), "u")
    assert "moved aside" not in quiet


def test_the_dashboards_gap_page_says_whose_the_folder_is_and_starts_no_diagnosis(app_env):
    from html import unescape

    from tests.api.ui.test_maintenance_forms import sign_in

    client, svc, keys, axis_id = app_env
    with session_scope(svc.factory) as s:
        axis = config_repo.get_axis(s, axis_id)
    write_dataset(svc.executor.dataset_folder(axis), _foreign_runs())
    csrf = sign_in(client, keys["operate"])
    page = unescape(client.get(f"/ui/axes/{axis_id}/gap").text)
    assert f"is not axis {axis_id}'s" in page and "move it aside" in page
    r = client.post(f"/ui/axes/{axis_id}/gap", data={"csrf": csrf}, follow_redirects=True)
    assert r.status_code == 200 and "move it aside" in unescape(r.text)
    assert svc.gap_jobs.pending_keys() == []  # nothing of the other machine's runs is diagnosed
