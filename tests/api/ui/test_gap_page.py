"""The gap page without a browser: it follows its job by id and always ends in the
report or a reason with what to do (a time-out, a job the service no longer knows), and
a run stored meanwhile keeps it on its job. The diagnosis is an in-process stand-in held
by an Event, so each state is seen deterministically."""

from __future__ import annotations

import re
import threading
from html import unescape
from pathlib import Path

import pytest
from fastapi.testclient import TestClient

from api.rest import create_app
from api.service.gap_jobs import DiagnosisTimedOut, dataset_of, stored_files
from storage.db import config_repo, session_scope
from tests.api.rest.conftest import FakeRunner, make_settings
from tests.api.rest.test_gap import store_case
from tests.api.ui.test_maintenance_forms import sign_in


@pytest.fixture
def env(tmp_path, monkeypatch):
    app = create_app(make_settings(f"sqlite:///{tmp_path}/g.sqlite3", tmp_path), runner=FakeRunner())
    with TestClient(app) as c:
        svc = app.state.service
        with session_scope(svc.factory) as s:
            key = config_repo.create_key(s, "ui-read", "read")[1]
            axis_id = config_repo.list_axes(s)[0].id
        release, outcome = threading.Event(), {}

        def stand_in(folder: str, plan: dict) -> dict:
            assert release.wait(60)
            if "error" in outcome:
                raise outcome["error"]
            used = [r.spec.file for r in dataset_of(Path(folder), plan["files"]).runs]
            return {"format": "mebm-gap/1", "effect": "cyclic_error", "gap_before_um": 3.0, "gap_after_um": 1.0,
                    "noise_floor_um": 0.2, "candidates": [], "runs_used": used, "report": "the report",
                    "computed_at": "2026-12-03T12:00:00+00:00", "residuals": []}

        monkeypatch.setattr(svc.gap_jobs, "compute", stand_in)
        monkeypatch.setattr(svc.gap_jobs, "use_process", False)
        store_case(svc, axis_id, "cyclic_error", seed=11)
        csrf = sign_in(c, key)
        yield c, svc, axis_id, csrf, release, outcome
        release.set()


def start(c, axis_id, csrf):
    r = c.post(f"/ui/axes/{axis_id}/gap", data={"csrf": csrf}, follow_redirects=False)
    assert r.status_code == 303
    return r.headers["location"]


def state(html: str) -> str:
    return re.search(r'data-gap="(\w+)"', html)[1]


def test_the_page_follows_its_job_to_the_report(env):
    c, svc, axis_id, csrf, release, _ = env
    page = c.get(f"/ui/axes/{axis_id}/gap").text
    folder = svc.executor.dataset_folder(next(iter(svc.executor._axes.values())))
    stored = len(stored_files(folder))  # fewer than the 16 asked for: the page promises those it will use
    assert stored < 16
    assert state(page) == "idle" and re.search(rf"about \d+ (s|min) for {stored} runs", unescape(page))
    where = start(c, axis_id, csrf)
    job_id = int(re.fullmatch(rf"/ui/axes/{axis_id}/gap\?job=(\d+)", where)[1])
    page = c.get(where).text
    assert state(page) in ("queued", "running")
    assert re.search(rf"(Waiting in the queue|Diagnosing) .*{stored} runs", unescape(page))
    assert f'data-poll="/ui/axes/{axis_id}/gap.frag?job={job_id}"' in page
    (folder / "dataset.json").touch()  # a new data version while it computes: still the same job
    frag = c.get(f"/ui/axes/{axis_id}/gap.frag?job={job_id}").text
    assert state(frag) in ("queued", "running") and f"(job {job_id}" in frag
    assert state(c.get(f"/ui/axes/{axis_id}/gap").text) in ("queued", "running")  # without the id too
    release.set()
    svc.gap_jobs.job(job_id).future.result(timeout=60)
    frag = c.get(f"/ui/axes/{axis_id}/gap.frag?job={job_id}").text
    assert state(frag) == "done" and "data-poll-stop" in frag and "Diagnosis: cyclic_error" in frag
    assert "No run stored since" in frag


def test_a_timed_out_diagnosis_says_why_and_offers_the_start_again(env):
    c, svc, axis_id, csrf, release, outcome = env
    outcome["error"] = DiagnosisTimedOut("the diagnosis of 16 runs ran longer than 900 s and was stopped. "
                                         "Diagnose fewer runs")
    release.set()
    where = start(c, axis_id, csrf)
    job_id = int(where.rsplit("=", 1)[1])
    svc.gap_jobs.job(job_id).future.exception(timeout=60)
    frag = unescape(c.get(f"/ui/axes/{axis_id}/gap.frag?job={job_id}").text)
    assert state(frag) == "failed" and "data-poll-stop" in frag
    assert f"The diagnosis (job {job_id}) ended without a report: the diagnosis of 16 runs ran longer" in frag
    assert 'id="gap-start"' in frag and "Start the diagnosis again" in frag
    del outcome["error"]
    again = start(c, axis_id, csrf)  # a start from the page computes a failure kept for its version anew
    assert again != where
    svc.gap_jobs.job(int(again.rsplit("=", 1)[1])).future.result(timeout=60)
    assert state(c.get(again).text) == "done"


def test_a_job_the_service_does_not_know_is_a_reason_not_the_idle_button(env):
    c, svc, axis_id, csrf, release, _ = env
    page = unescape(c.get(f"/ui/axes/{axis_id}/gap?job=4711").text)
    assert state(page) == "lost"
    assert "The page cannot follow its diagnosis: this diagnosis is no longer known to the service" in page
    assert "Start the diagnosis again" in page and "data-poll=" not in page
