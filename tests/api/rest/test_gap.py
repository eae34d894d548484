"""GET /axes/{id}/gap: the gap diagnosis on an axis' stored runs."""

import functools
import time
from dataclasses import replace

import numpy as np
import pytest

from core.gap import diagnose
from core.gap_benchmark import SMALL, make_case
from storage.dataset import write_dataset
from storage.db import config_repo, session_scope
from tests.api.rest.conftest import hdr

# The stored runs of the REST and dashboard tests: one axis' round trips of the
# benchmark's small case (two train runs and one test run, no circles). Their diagnosis is
# a valid one (a cyclic_error case is named and its gap shrinks to a twentieth) in a
# quarter of the time the whole small case takes; what the diagnosis finds is tested in
# tests/core/gap/, these tests test how the service serves it.
API_CASE = replace(SMALL, circles_train=0, circles_test=0)


def api_case(label, seed):
    """The case of ``label`` with the runs of its last axis only."""
    case = make_case(label, np.random.default_rng(seed), API_CASE)
    axis = case.dataset.runs[-1].spec.axes
    runs = tuple(r for r in case.dataset.runs if r.spec.axes == axis)
    return replace(case, dataset=replace(case.dataset, runs=runs))


def store_case(svc, axis_id, label, seed, case=None):
    """Store ``case`` (default: ``api_case(label, seed)``) as the axis' runs."""
    with session_scope(svc.factory) as s:
        axis = config_repo.get_axis(s, axis_id)
    case = case or api_case(label, seed)
    write_dataset(svc.executor.dataset_folder(axis), case.dataset)
    return case


@functools.cache
def _direct_diagnosis(label, seed):
    """The core diagnosis of the case ``store_case`` stores, once per test process: the
    backends' tests compare their REST body with the same report."""
    return diagnose(api_case(label, seed).dataset)


def get_report(client, url, headers, timeout_s=600.0):
    """Poll as an MES would: 202 with Retry-After until the report is ready. The deadline
    only catches a diagnosis that never ends, on however busy a machine."""
    deadline = time.monotonic() + timeout_s
    while True:
        r = client.get(url, headers=headers)
        if r.status_code != 202:
            return r
        assert int(r.headers["Retry-After"]) > 0 and r.json()["status"] == "computing"
        assert time.monotonic() < deadline, "the diagnosis never finished"
        time.sleep(0.5)


def test_no_stored_runs_is_404(app_env):
    client, _svc, keys, axis_id = app_env
    r = client.get(f"/api/v1/axes/{axis_id}/gap", headers=hdr(keys["read"]))
    assert r.status_code == 404
    assert "stored runs" in r.json()["detail"]


def test_diagnoses_stored_runs_with_the_spec_contract(app_env):
    client, svc, keys, axis_id = app_env
    case = store_case(svc, axis_id, "cyclic_error", seed=11)
    r = get_report(client, f"/api/v1/axes/{axis_id}/gap", hdr(keys["read"]))
    assert r.status_code == 200, r.text
    d = r.json()
    assert d["format"] == "mebm-gap/1"
    # exactly what the core diagnosis says of the same runs held in memory (the stored
    # CSVs round-trip losslessly), plus the human report and the runs used
    expected = _direct_diagnosis("cyclic_error", 11)
    assert {k: d[k] for k in expected.to_dict()} == expected.to_dict()
    n = len(case.dataset.runs)  # the report begins with the period: runs written without times or repairs
    assert d["report"] == (f"Runs used: {n} stored run(s), measurement times not recorded.\n"
                           "No repair is recorded for the axis: the runs are one period.\n"
                           "Repairs within the period: none.\n\n" + expected.text())
    assert d["runs_used"] == [run.spec.file for run in case.dataset.runs]
    assert d["effect"] == case.label
    assert d["gap_after_um"] < d["gap_before_um"]
    # the next call is served from the cache at once, without reading the runs again (every
    # run is damaged, dataset.json, the data version, is not): same body, with its age
    folder = svc.executor.dataset_folder(next(iter(svc.executor._axes.values())))
    for run in case.dataset.runs:
        (folder / run.spec.file).write_text("time_s\n0\n")
    again = client.get(f"/api/v1/axes/{axis_id}/gap", headers=hdr(keys["read"]))
    assert again.status_code == 200
    later = again.json()
    assert later.pop("age_s") >= d.pop("age_s") >= 0 and later == d
    assert "residuals" not in d  # the dashboard's curves stay out of the API's body


def test_one_run_is_422_and_a_train_and_a_test_run_are_diagnosed(app_env):
    client, svc, keys, axis_id = app_env
    # the whole small case: its newest two runs are a train and a test circle (a diagnosis of a second)
    store_case(svc, axis_id, "none", seed=12, case=make_case("none", np.random.default_rng(12), SMALL))
    r = client.get(f"/api/v1/axes/{axis_id}/gap?runs=1", headers=hdr(keys["read"]))
    assert r.status_code == 422 and "runs" in r.json()["detail"]
    r = get_report(client, f"/api/v1/axes/{axis_id}/gap?runs=2", hdr(keys["read"]))
    assert r.status_code == 200, r.text
    doc = r.json()
    assert len(doc["split"]["train"]) == 1 and len(doc["split"]["test"]) == 1, doc["split"]


@pytest.mark.parametrize("key", [None, "mebm_not_a_key"])
def test_needs_a_valid_key(app_env, key):
    client, _svc, _keys, axis_id = app_env
    r = client.get(f"/api/v1/axes/{axis_id}/gap", headers=hdr(key) if key else {})
    assert r.status_code == 401
