"""The status is computed in the transaction that stores a cycle and published
after its commit, so the first poll after a cycle does not pay for the recomputation, and
a client that saw the new measurement never gets a status without it. Past MAX_ROWS the
history fit is redone once per thinning step, not after every cycle."""

from __future__ import annotations

import threading

import pytest

import api.service.prognosis as prognosis_mod
import api.service.status as status_mod
from api.rest.limits import TokenBucket
from api.service.status import StatusCache
from storage.db import results_repo, session_scope
from tests.api.rest.conftest import hdr
from tests.api.rest.test_api import V1, run_cycle
from tests.api.rest.test_prognosis import bulk_history


def _counting(monkeypatch, module, name):
    calls = []
    real = getattr(module, name)

    def counted(*a, **k):
        calls.append(threading.current_thread().name)
        return real(*a, **k)

    monkeypatch.setattr(module, name, counted)
    return calls


def test_the_first_poll_after_a_cycle_finds_its_status_computed(app_env, runner, monkeypatch):
    client, svc, keys, axis_id = app_env
    h = hdr(keys["read"])
    runner.backlash_um = 150.0
    run_cycle(client, svc, keys, axis_id)
    assert client.get(f"{V1}/axes/{axis_id}/status", headers=h).json()["backlash_mean_um"] == pytest.approx(150.0, abs=1)
    seen = []
    real_after = svc.maintenance.after_cycle

    def after_cycle(a, cycle, alerts):  # the first listener told of the stored cycle
        seen.append(svc.status.fresh(a))
        return real_after(a, cycle, alerts)

    monkeypatch.setattr(svc.maintenance, "after_cycle", after_cycle)
    computed = _counting(monkeypatch, status_mod, "compute_status")
    runner.backlash_um = 180.0
    run_cycle(client, svc, keys, axis_id)
    # published with the commit: a poll at that moment is not left to recompute it
    assert seen and seen[0] is not None and seen[0].latest.round_trip.backlash.mean_um == pytest.approx(180.0, abs=1)
    assert len(computed) == 1  # once, in the transaction that stored the cycle
    st = client.get(f"{V1}/axes/{axis_id}/status", headers=h).json()
    assert len(computed) == 1, computed  # the poll did not recompute it
    newest = client.get(f"{V1}/axes/{axis_id}/measurements?limit=1", headers=h).json()["items"][0]
    assert st["backlash_mean_um"] == pytest.approx(180.0, abs=1)
    assert st["measurement_id"] == newest["id"], (st, newest)


def test_a_status_computed_before_the_commit_does_not_replace_the_published_one(app_env, runner, monkeypatch):
    """A poller that read the database before the commit returns what it read, but the
    cache keeps the status published with the cycle."""
    client, svc, keys, axis_id = app_env
    runner.backlash_um = 150.0
    run_cycle(client, svc, keys, axis_id)
    cache = StatusCache(svc.factory)
    started, release = threading.Event(), threading.Event()
    real = status_mod.compute_status

    def slow(s, a, memo=None):
        st = real(s, a, memo)
        if threading.current_thread().name == "poller":
            started.set()
            assert release.wait(10)
        return st

    monkeypatch.setattr(status_mod, "compute_status", slow)
    got = {}
    poller = threading.Thread(target=lambda: got.setdefault("st", cache.get(axis_id)), name="poller")
    poller.start()
    assert started.wait(10)
    runner.backlash_um = 180.0
    run_cycle(client, svc, keys, axis_id)  # stored with the service's cache; this one is told as the executor does
    with session_scope(svc.factory) as s:
        publish = cache.prepare(s, axis_id)
    publish()
    release.set()
    poller.join(10)
    assert got["st"].latest.round_trip.backlash.mean_um == pytest.approx(150.0, abs=1)  # what it read
    assert cache.fresh(axis_id).latest.round_trip.backlash.mean_um == pytest.approx(180.0, abs=1)


def test_a_prepared_status_that_is_not_published_leaves_nothing(app_env, runner):
    """The storing transaction rolled back: the cache keeps what it had, and the history
    memo does not keep what was computed inside the transaction. An invalidation between
    the commit and the publication (the axis changed) wins over the publication."""
    client, svc, keys, axis_id = app_env
    runner.backlash_um = 150.0
    run_cycle(client, svc, keys, axis_id)
    cache = StatusCache(svc.factory)
    before = cache.get(axis_id)
    runner.backlash_um = 180.0
    run_cycle(client, svc, keys, axis_id)  # the database has moved on; this cache was not told
    with session_scope(svc.factory) as s:
        prepared = cache.prepare(s, axis_id)  # never published
    assert prepared is not None and cache.fresh(axis_id) is before
    assert cache._history_memo.last(axis_id, "answers")[1] is before.history
    with session_scope(svc.factory) as s:
        publish = cache.prepare(s, axis_id)
    cache.invalidate(axis_id)  # e.g. the axis' tasks changed between the commit and the publication
    publish()
    assert cache.fresh(axis_id) is None and cache._history_memo.last(axis_id, "answers")[1] is before.history
    assert cache.get(axis_id).latest.round_trip.backlash.mean_um == pytest.approx(180.0, abs=1)


def test_a_failing_status_computation_does_not_lose_the_cycle(app_env, runner, monkeypatch):
    client, svc, keys, axis_id = app_env
    h = hdr(keys["read"])

    def broken(s, a, memo=None):
        results_repo.latest_result(s, a)  # the transaction has read, then it fails
        raise RuntimeError("status bug")

    monkeypatch.setattr(status_mod, "compute_status", broken)
    runner.backlash_um = 170.0
    run_cycle(client, svc, keys, axis_id)
    monkeypatch.undo()
    items = client.get(f"{V1}/axes/{axis_id}/measurements", headers=h).json()["items"]
    assert [c["status"] for c in items] == ["ok"]
    assert client.get(f"{V1}/axes/{axis_id}/status", headers=h).json()["backlash_mean_um"] == pytest.approx(170.0, abs=1)


def test_past_max_rows_the_history_fit_is_redone_once_per_thinning_step(app_env, runner, monkeypatch):
    client, svc, keys, axis_id = app_env
    client.app.state.trigger_limit = TokenBucket(60.0, 100)  # (the trigger limit is tested in test_bounds)
    monkeypatch.setattr(prognosis_mod, "MAX_ROWS", 20)
    runner.backlash_um, runner.temperature_c = 200.0, 20.0
    run_cycle(client, svc, keys, axis_id)
    bulk_history(svc, axis_id, n=60)  # 61 rows with a temperature: every 4th is read
    reads = _counting(monkeypatch, prognosis_mod.results_repo, "history_rows")
    svc.status.get(axis_id)
    assert len(reads) == 1
    for i in range(8):
        run_cycle(client, svc, keys, axis_id)
    assert len(reads) == 3, reads  # 62..69 rows: refitted at 65 and 69, not 8 times
    st = svc.status.get(axis_id)
    assert st.latest is not None and st.history.rows_total == 69 and st.history.rows_used == 18
    monkeypatch.setattr(prognosis_mod, "MAX_ROWS", 3000)  # up to MAX_ROWS: on every new measurement
    svc.status.invalidate(axis_id)
    svc.status.get(axis_id)  # the same history: not read again
    assert len(reads) == 3
    run_cycle(client, svc, keys, axis_id)
    run_cycle(client, svc, keys, axis_id)
    assert len(reads) == 5
