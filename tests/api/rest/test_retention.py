"""Retention in the service: raw runs are capped per axis, result rows never dropped,
disk use per axis in /metrics."""

from __future__ import annotations

from dataclasses import replace

from storage.dataset import read_dataset
from storage.retention import RetentionPolicy, folder_bytes
from storage.db import results_repo, session_scope
from tests.api.rest.conftest import hdr


def test_retention_caps_raw_runs_keeps_every_result_and_reports_disk_use(app_env):
    client, svc, keys, axis_id = app_env
    for _ in range(4):
        svc.scheduler.request(axis_id, "schedule")
        assert svc.scheduler.idle(30)
    svc.settings = replace(svc.settings, retention=RetentionPolicy(keep_last_runs=1, keep_around_events=0, max_runs=2))
    before = svc.apply_retention()[axis_id]
    (axis,) = [a for a in svc.executor._axes.values() if a.id == axis_id]
    folder = svc.executor.dataset_folder(axis)
    runs = read_dataset(folder).runs
    assert len(runs) == 2 and len(list(folder.glob("*.csv.gz"))) == 1 and len(list(folder.glob("*.csv"))) == 1
    with session_scope(svc.factory) as s:
        cycles = results_repo.list_measurements(s, axis_id, status="ok")[1]
    assert len(cycles) == 4  # no result row dropped
    # the two oldest runs are gone, and their cycles say why; the two kept say nothing
    oldest_first = sorted(cycles, key=lambda c: c.id)
    assert [c.raw_run_lost is not None for c in oldest_first] == [True, True, False, False]
    assert oldest_first[0].raw_run_lost.startswith("deleted by the retention policy on ")
    assert "max_runs=2" in oldest_first[0].raw_run_lost
    text = client.get("/metrics", headers=hdr(keys["read"])).text
    line = next(x for x in text.splitlines() if x.startswith(f'mebm_dataset_bytes{{axis_id="{axis_id}"}}'))
    assert float(line.split()[-1]) == before == folder_bytes(folder) > 0
