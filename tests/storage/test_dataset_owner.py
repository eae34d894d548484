"""dataset.json's optional ``owner``: recorded by a writer that names one, checked before
any append, kept by writers that name none, and optional for readers."""

from __future__ import annotations

import json

import pytest

from core.dataset import Dataset
from storage.dataset import FolderOwnerError, append_runs, folder_owner, read_dataset, set_owner, write_dataset
from tests.storage.test_dataset import MACHINE, small_run

A = {"machine_uuid": "11111111-1111-4111-8111-111111111111", "axis_uuid": "22222222-2222-4222-8222-222222222222",
     "machine": "m1", "axis": "y"}
B = {**A, "machine_uuid": "33333333-3333-4333-8333-333333333333"}


def _listing(folder):
    return sorted(p.name for p in folder.iterdir())


def test_a_new_folder_records_its_owner_after_the_format(tmp_path):
    folder = append_runs(tmp_path / "ds", MACHINE, [small_run()], owner=A)
    doc = json.loads((folder / "dataset.json").read_text())
    assert doc["owner"] == A and list(doc)[:2] == ["format", "owner"]
    assert folder_owner(read_dataset(folder).extra) == A
    append_runs(folder, MACHINE, [small_run("rt_y_01.csv")], owner={**A, "machine": "renamed"})  # names only inform
    assert len(read_dataset(folder).runs) == 2


def test_another_owners_folder_is_not_appended_to(tmp_path):
    folder = append_runs(tmp_path / "ds", MACHINE, [small_run()], owner=A)
    before = (folder / "dataset.json").read_text(), _listing(folder)
    with pytest.raises(FolderOwnerError, match="33333333.*not appended to|belongs to.*1111"):
        append_runs(folder, MACHINE, [small_run("rt_y_01.csv")], owner=B)
    assert ((folder / "dataset.json").read_text(), _listing(folder)) == before


def test_a_folder_without_owner_is_readable_and_refused_to_an_owned_writer_while_it_holds_runs(tmp_path):
    folder = write_dataset(tmp_path / "ds", Dataset(MACHINE, (small_run(),), extra={"source": "before"}))
    ds = read_dataset(folder)  # folders written before the key: read as ever
    assert folder_owner(ds.extra) is None and len(ds.runs) == 1
    with pytest.raises(FolderOwnerError, match="no owner and holds 1 run"):
        append_runs(folder, MACHINE, [small_run("rt_y_01.csv")], owner=A)
    assert len(read_dataset(folder).runs) == 1 and not (folder / "rt_y_01.csv").exists()
    set_owner(folder, A)  # adopted
    append_runs(folder, MACHINE, [small_run("rt_y_01.csv")], owner=A)
    ds = read_dataset(folder)
    assert len(ds.runs) == 2 and ds.extra["source"] == "before" and folder_owner(ds.extra) == A
    with pytest.raises(FolderOwnerError):  # adopting does not take a folder from its owner
        set_owner(folder, B)
    assert folder_owner(read_dataset(folder).extra) == A


def test_an_empty_folder_without_owner_is_taken_and_a_writer_naming_none_keeps_the_owner(tmp_path):
    folder = write_dataset(tmp_path / "ds", Dataset(MACHINE, ()))
    append_runs(folder, MACHINE, [small_run()], owner=A)
    append_runs(folder, MACHINE, [small_run("rt_y_01.csv")])  # the CLI (mebm import, mebm sim)
    assert folder_owner(read_dataset(folder).extra) == A and len(read_dataset(folder).runs) == 2


def test_a_malformed_owner_is_no_owner(tmp_path):
    folder = write_dataset(tmp_path / "ds", Dataset(MACHINE, (small_run(),), extra={"owner": {"machine_uuid": 7}}))
    assert folder_owner(read_dataset(folder).extra) is None
    with pytest.raises(FolderOwnerError):
        append_runs(folder, MACHINE, [small_run("rt_y_01.csv")], owner=A)
