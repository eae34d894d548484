"""A full disk loses nothing that was measured: the data folder (and the SQLite database in
it) on a small tmpfs filled to the last block while a cycle runs; a normal stop; a restart
once there is room. The cycle is kept with the reason code storage_full, shown so (never
running) while it waits, and no empty file is left behind. Below the free-disk floor no
cycle is started, and /healthz and an alert say why. A restart while the disk is still
full starts (even when SQLite cannot open its database), says why on /healthz, keeps the
spooled cycle as it is and stores it once there is room, without another restart."""

from __future__ import annotations

import errno
import os
import subprocess
import threading
from dataclasses import replace
from pathlib import Path

import pytest
from fastapi.testclient import TestClient

from api.rest import create_app
from storage.db import DatabaseUnavailableError, config_repo, results_repo, session_scope
from tests.api.rest.conftest import FakeRunner, hdr, make_settings


@pytest.fixture
def small_disk(tmp_path):
    """A 5 MB tmpfs (root only), unmounted afterwards."""
    mnt = tmp_path / "disk"
    mnt.mkdir()
    if os.geteuid() != 0:
        pytest.skip("mounting a tmpfs needs root")
    r = subprocess.run(["mount", "-t", "tmpfs", "-o", "size=5m", "tmpfs", str(mnt)], capture_output=True, text=True)
    if r.returncode != 0:
        pytest.skip(f"no tmpfs here: {r.stderr.strip()}")
    try:
        yield mnt
    finally:
        subprocess.run(["umount", "-l", str(mnt)], check=False)


def _write_until_full(filler: Path, flags: int) -> None:
    """Write to ``filler`` until the disk refuses another byte."""
    fd = os.open(filler, os.O_WRONLY | flags, 0o600)
    try:
        for size in (65536, 512, 1):  # down to the last byte
            try:
                while True:
                    os.write(fd, b"\xff" * size)
            except OSError as exc:
                assert exc.errno == errno.ENOSPC
    finally:
        os.close(fd)


def _fill(disk: Path) -> Path:
    """Write a filler file until the disk refuses another byte."""
    filler = disk / "filler"
    _write_until_full(filler, os.O_CREAT | os.O_TRUNC)
    return filler


def _empty_files(root: Path) -> list[Path]:
    """Empty files, but the folders' lock files (empty by design: flock targets)."""
    return [p for p in root.rglob("*") if p.is_file() and p.stat().st_size == 0 and not p.name.endswith(".lock")]


def _reserved(p: Path) -> bool:
    """The spool reserve, a spool slot or the loss ledger (written while there is room, by design)."""
    return p.name in (".reserve", ".ledger") or (p.name.startswith(".slot-") and p.name[6:].isdigit())


def _keys(svc) -> tuple[dict, int]:
    keys = {}
    with session_scope(svc.factory) as s:
        for role in ("read", "operate"):
            keys[role] = config_repo.create_key(s, f"test-{role}", role)[1]
        axis_id = config_repo.list_axes(s)[0].id
    return keys, axis_id


def _wait(cond, timeout_s=30.0) -> bool:
    done = threading.Event()
    for _ in range(int(timeout_s / 0.05)):
        if cond():
            return True
        done.wait(0.05)
    return cond()


def _full_disk_cycle(small_disk, database_full=False, no_room_for_run=False, spool_refused=False):
    """Start on the small disk, run a cycle that finishes once the disk is full, stop
    normally, free the space and start again. Returns (data folder, uuid, what was seen while
    the disk was full, the restarted app's measurements, alerts, start report, executor)."""
    data, uuid, seen, settings, keys, axis_id, filler = _finish_on_full_disk(
        small_disk, database_full=database_full, no_room_for_run=no_room_for_run, spool_refused=spool_refused)
    filler.unlink()  # the operator frees space, then restarts
    app = create_app(settings, runner=FakeRunner())
    with TestClient(app) as client:
        svc = app.state.service
        items = client.get(f"/api/v1/axes/{axis_id}/measurements", headers=hdr(keys["read"])).json()["items"]
        alerts = client.get("/api/v1/alerts", headers=hdr(keys["read"])).json()["items"]
        assert svc.executor.pending() == [] and svc.executor.held() == {}
        assert _wait(svc.executor.reserve_ok)  # allocated again
        report = svc.report
    assert _empty_files(data) == []
    assert not [p for p in data.rglob(".*") if not _reserved(p) and not p.name.endswith(".lock")]  # no temp file
    return data, uuid, seen, items, alerts, report


def _finish_on_full_disk(small_disk, database_full=False, no_room_for_run=False, spool_refused=False):
    """Start on the small disk, run a cycle that finishes once the disk is full and stop
    normally, the disk still full. Returns (data folder, uuid, what was seen while the disk
    was full, the settings, the keys, the axis id, the filler file)."""
    data = small_disk / "data"
    settings = replace(make_settings("sqlite://", data), database_url=None, min_free_disk_mb=0.0,
                       spool_reserve_mb=1.0, spool_slots=2, spool_slot_mb=0.4)  # SQLite under the data folder
    runner = FakeRunner()
    runner.gate = threading.Event()
    runner.gate_timeout_s = 60.0
    app = create_app(settings, runner=runner)
    seen = {}
    real_save = results_repo.save_finished_cycle

    def refuse(s, fc):  # SQLite under the data folder finds no page either (its WAL may have had room)
        raise DatabaseUnavailableError("database unavailable: database or disk is full")

    with TestClient(app) as client:
        svc = app.state.service
        keys, axis_id = _keys(svc)
        assert svc.executor.reserve_path.stat().st_size >= 1_000_000  # allocated while there was room
        r = client.post(f"/api/v1/axes/{axis_id}/measurements", headers=hdr(keys["operate"]))
        assert r.status_code in (200, 201, 202), r.text
        uuid = r.json()["uuid"]
        assert runner.running.wait(30)  # marked running, measuring
        filler = _fill(small_disk)
        if database_full:
            results_repo.save_finished_cycle = refuse
        if no_room_for_run:  # a raw run larger than the reserve: neither the folder nor unfiled/ takes it

            def no_room(*a, **k):
                raise OSError(errno.ENOSPC, "No space left on device")

            svc.executor._write_run = no_room
            svc.executor._keep_trace = lambda *a, **k: None
        if spool_refused:  # until the stop: the cycle is kept in memory meanwhile
            svc.executor._write_spool = lambda doc: None
        try:
            runner.gate.set()
            assert svc.scheduler.idle(60)
        finally:
            results_repo.save_finished_cycle = real_save
        assert not svc.executor.reserve_path.exists()  # released to keep the cycle
        seen["items"] = client.get(f"/api/v1/axes/{axis_id}/measurements", headers=hdr(keys["read"])).json()["items"]
        seen["health"] = client.get("/healthz").json()
        seen["status"] = client.get(f"/api/v1/axes/{axis_id}/status", headers=hdr(keys["read"])).json()
        seen["spooled"] = (svc.executor.spool_dir / f"{uuid}.json").is_file()
        seen["in_memory"] = [fc.uuid for fc in svc.executor.unsaved]
        if spool_refused:
            del svc.executor._write_spool  # the stop writes it (the reserve's room is free)
    # a normal stop: the cycle is in the spool or in the database; no empty file anywhere
    seen["spooled_after_stop"] = (data / "spool" / f"{uuid}.json").is_file()
    seen["empty_after_stop"] = _empty_files(data)
    return data, uuid, seen, settings, keys, axis_id, filler


def _assert_kept_as_storage_full(items, alerts):
    (item,) = items
    assert item["status"] == "ok" and item["backlash_mean_um"] is not None  # the measurement itself
    assert item["reason_code"] == "storage_full" and item["failure_reason"].startswith("storage_full:")
    assert "free space under the data folder" in item["failure_reason"]
    assert item["raw_run_lost"] is None
    assert [a["kind"] for a in alerts if a["active"]] == ["storage_full"]


def test_a_cycle_finished_on_a_full_disk_survives_a_stop_and_a_restart_as_storage_full(small_disk):
    data, uuid, seen, items, alerts, report = _full_disk_cycle(small_disk)
    assert seen["empty_after_stop"] == []
    (during,) = seen["items"]
    assert during["status"] != "running" and during["reason_code"] == "storage_full"
    assert seen["status"]["last_cycle_status"] != "running"
    assert report.interrupted == 0
    _assert_kept_as_storage_full(items, alerts)


def test_a_cycle_the_full_database_refuses_waits_in_the_spool_across_a_stop_and_a_restart(small_disk):
    data, uuid, seen, items, alerts, report = _full_disk_cycle(small_disk, database_full=True)
    assert seen["spooled"] and seen["spooled_after_stop"]  # kept on disk, in the reserve's room
    assert seen["empty_after_stop"] == []
    (during,) = seen["items"]
    assert during["status"] == "failed" and during["reason_code"] == "storage_full"  # finished, not running
    assert seen["status"]["last_cycle_status"] == "failed"
    assert seen["status"]["last_failure_reason"].startswith("storage_full:")
    assert any(p.startswith("storage_full") for p in seen["health"]["problems"])
    assert report.replayed == 1 and report.interrupted == 0
    _assert_kept_as_storage_full(items, alerts)


def test_below_the_free_disk_floor_no_cycle_starts_and_healthz_and_an_alert_say_why(engine, db_url, tmp_path):
    runner = FakeRunner()
    settings = make_settings(db_url, tmp_path, min_free_disk_mb=1e12)  # more than any disk has
    app = create_app(settings, runner=runner)
    with TestClient(app) as client:
        svc = app.state.service
        keys, axis_id = _keys(svc)
        r = client.post(f"/api/v1/axes/{axis_id}/measurements", headers=hdr(keys["operate"]))
        assert r.status_code in (200, 201, 202), r.text
        assert svc.scheduler.idle(30)
        assert runner.calls == 0  # the axis was not moved
        (item,) = client.get(f"/api/v1/axes/{axis_id}/measurements", headers=hdr(keys["read"])).json()["items"]
        assert item["status"] == "cancelled" and item["reason_code"] == "storage_full"
        assert "below the floor" in item["failure_reason"] and "free space" in item["failure_reason"]
        health = client.get("/healthz")
        assert health.status_code == 503
        assert any("no new cycle is started" in p for p in health.json()["problems"])
        alerts = client.get("/api/v1/alerts", headers=hdr(keys["read"])).json()["items"]
        (alert,) = [a for a in alerts if a["kind"] == "storage_full"]
        assert alert["active"] and "min_free_disk_mb" in alert["message"]


def test_a_raw_run_with_no_room_anywhere_travels_in_the_spool_file_and_is_kept_at_the_restart(small_disk):
    data, uuid, seen, items, alerts, report = _full_disk_cycle(small_disk, database_full=True, no_room_for_run=True)
    assert seen["spooled_after_stop"] and seen["empty_after_stop"] == []
    (during,) = seen["items"]
    assert during["status"] == "failed" and during["reason_code"] == "storage_full"
    assert seen["status"]["last_cycle_status"] == "failed"
    assert report.replayed == 1 and report.interrupted == 0
    _assert_kept_as_storage_full(items, alerts)  # re-analysed from the trace the spool file carried
    assert (data / "unfiled" / f"{uuid}.npz").is_file()  # and the raw run kept now that there is room
    assert "unfiled" in items[0]["failure_reason"]


def test_the_spool_reserve_is_configured_in_storage_and_refuses_a_negative_size():
    from api.service.config.loading import parse_settings
    from api.service.config.settings import ConfigError

    assert parse_settings({"storage": {"spool_reserve_mb": 2.5}}).spool_reserve_mb == 2.5
    assert parse_settings({}).spool_reserve_mb == 16.0
    with pytest.raises(ConfigError, match="spool_reserve_mb"):
        parse_settings({"storage": {"spool_reserve_mb": -1}})
    assert parse_settings({"storage": {"spool_slots": 0, "spool_slot_mb": 0.5}}).spool_slots == 0
    for bad in ({"spool_slots": 65}, {"spool_slots": -1}, {"spool_slot_mb": 0.001}, {"spool_slot_mb": 100.0}):
        with pytest.raises(ConfigError, match=next(iter(bad))):
            parse_settings({"storage": bad})


def test_a_cycle_kept_in_memory_on_a_full_disk_is_written_to_the_spool_at_a_normal_stop(small_disk):
    data, uuid, seen, items, alerts, report = _full_disk_cycle(small_disk, database_full=True, spool_refused=True)
    assert seen["in_memory"] == [uuid] and not seen["spooled"]
    (during,) = seen["items"]
    assert during["status"] == "failed" and during["reason_code"] == "storage_full"  # finished, not running
    assert seen["status"]["last_cycle_status"] == "failed"
    assert seen["status"]["last_failure_reason"].startswith("storage_full:")
    assert seen["spooled_after_stop"] and seen["empty_after_stop"] == []  # flushed by the stop
    assert report.replayed == 1 and report.interrupted == 0
    _assert_kept_as_storage_full(items, alerts)


def _fill_again(filler: Path) -> None:
    """Take every byte the stop freed (another writer on the same disk)."""
    _write_until_full(filler, os.O_APPEND)


def _no_wal(db: Path) -> None:
    """The write-ahead log emptied into the database and truncated: SQLite must then find
    room for its log and shared-memory index to open the database at all."""
    import sqlite3

    con = sqlite3.connect(db)
    try:
        assert con.execute("PRAGMA wal_checkpoint(TRUNCATE)").fetchone()[0] == 0
    finally:
        con.close()


@pytest.mark.parametrize("full", ["database_refuses_the_cycle", "database_cannot_be_opened"])
def test_a_restart_while_the_disk_is_still_full_starts_keeps_the_spooled_cycle_and_stores_it_once_there_is_room(
        small_disk, full):
    data, uuid, seen, settings, keys, axis_id, filler = _finish_on_full_disk(small_disk, database_full=True)
    assert seen["spooled_after_stop"]
    spooled = data / "spool" / f"{uuid}.json"
    (kept_id,) = [i["id"] for i in seen["items"]]
    # the operator restarts before freeing any space; below the floor no cycle may start
    settings = replace(settings, min_free_disk_mb=2.0, spool_retry_s=0.2)
    real_save = results_repo.save_finished_cycle
    if full == "database_cannot_be_opened":
        _no_wal(data / "mebm.sqlite3")
        _fill_again(filler)
    else:  # the database opens (its log has room) but the kept cycle's rows (curves) find no page

        def refuse(s, fc):
            if fc.uuid == uuid:
                raise DatabaseUnavailableError("database unavailable: database or disk is full")
            return real_save(s, fc)

        results_repo.save_finished_cycle = refuse
    runner = FakeRunner()
    app = create_app(settings, runner=runner)
    try:
        with TestClient(app) as client:  # it starts
            svc = app.state.service
            health = client.get("/healthz")
            assert health.status_code == 503, health.text
            body = health.json()
            assert any("no new cycle is started" in p for p in body["problems"]), body  # the floor
            assert any(p.startswith("storage_full") for p in body["problems"]), body
            assert body["spooled_cycles"] == 1 and spooled.is_file()  # still kept, waiting for room
            r = client.post(f"/api/v1/axes/{axis_id}/measurements", headers=hdr(keys["operate"]))
            if full == "database_cannot_be_opened":
                assert any("cannot be opened" in p for p in body["problems"]), body
                assert body["database"] == "unavailable"
                assert r.status_code == 503, r.text  # nothing is queued without the database
                assert svc.report.waiting_for_room and svc.report.interrupted == 0
            else:
                assert r.status_code in (200, 201, 202), r.text
                assert svc.scheduler.idle(30)
                m = client.get(f"/api/v1/measurements/{r.json()['measurement']['id']}", headers=hdr(keys["read"]))
                assert m.json()["status"] == "cancelled" and m.json()["reason_code"] == "storage_full"
                (during,) = [i for i in client.get(f"/api/v1/axes/{axis_id}/measurements",
                                                   headers=hdr(keys["read"])).json()["items"] if i["id"] == kept_id]
                assert during["status"] == "failed" and during["reason_code"] == "storage_full"  # not interrupted
                assert svc.report.interrupted == 0 and svc.report.replayed == 0
            assert runner.calls == 0  # below the floor: the axis was not moved
            results_repo.save_finished_cycle = real_save
            filler.unlink()  # room again: the kept cycle is stored without another restart
            assert _wait(lambda: svc.waiting_for_room is None and svc.executor is not None
                         and not svc.executor.has_pending(), 30), svc.health.report().problems
            assert not spooled.exists()
            items = client.get(f"/api/v1/axes/{axis_id}/measurements", headers=hdr(keys["read"])).json()["items"]
            alerts = client.get("/api/v1/alerts", headers=hdr(keys["read"])).json()["items"]
            assert _wait(svc.executor.reserve_ok)
            svc.health.invalidate()
            assert client.get("/healthz").status_code == 200, client.get("/healthz").text
            assert svc.report.interrupted == 0
    finally:
        results_repo.save_finished_cycle = real_save
    _assert_kept_as_storage_full([i for i in items if i["id"] == kept_id], alerts)
    assert [i["status"] for i in items if i["id"] != kept_id] in ([], ["cancelled"])  # no cycle ran meanwhile
    assert _empty_files(data) == []


def test_the_start_banner_says_the_service_waits_for_disk_and_gives_no_sign_in_link_without_a_database(tmp_path):
    from api.cli.serve import banner, sign_in_link
    from api.service.service import StartReport

    why = "the database …/mebm.sqlite3 cannot be opened: the disk under it is full (0.0 MB free)"
    report = StartReport(database="sqlite:///x", replayed=0, interrupted=0, created_axes=(), demo_keys={},
                         simulators={}, bootstrap_admin=None, waiting_for_room=why)
    settings = replace(make_settings("sqlite:///x", tmp_path), demo_keys=True)
    (tmp_path / "demo-keys.json").write_text('{"read": "mebm_kept"}')

    class NoDatabase:
        def issue_link(self, secret):
            raise DatabaseUnavailableError("database unavailable: not open yet")

    link, path, error = sign_in_link(settings, report, "http://127.0.0.1:1", NoDatabase())
    assert link is None and path is None and "not open yet" in error
    text = banner(settings, report, "http://127.0.0.1:1", sign_in_error=error)
    assert f"WAITING FOR DISK: {why}" in text and "no sign-in link" in text
    assert not (tmp_path / "sign-in-link").exists()


def test_a_start_on_a_disk_too_full_to_open_sqlite_answers_healthz_and_completes_once_there_is_room(
        tmp_path, monkeypatch):
    """The same without root: the disk's fullness and SQLite's refusal to open are played."""
    import shutil

    import api.service.service as service_module

    settings = replace(make_settings("sqlite://", tmp_path / "data"), database_url=None, min_free_disk_mb=0.0,
                       spool_retry_s=0.1)
    first = create_app(settings, runner=FakeRunner())
    with TestClient(first) as client:
        keys, axis_id = _keys(first.state.service)
    full = threading.Event()
    full.set()
    real_usage, real_ping = shutil.disk_usage, service_module.ping

    def usage(path):
        u = real_usage(path)
        return u._replace(free=0) if full.is_set() else u

    def ping(engine):
        if full.is_set():
            raise DatabaseUnavailableError("database unavailable: disk I/O error")
        real_ping(engine)

    monkeypatch.setattr(shutil, "disk_usage", usage)
    monkeypatch.setattr(service_module, "ping", ping)
    runner = FakeRunner()
    app = create_app(settings, runner=runner)
    with TestClient(app) as client:  # it starts
        svc = app.state.service
        assert svc.report.waiting_for_room and "cannot be opened" in svc.report.waiting_for_room
        health = client.get("/healthz")
        assert health.status_code == 503 and health.json()["database"] == "unavailable"
        assert any(p.startswith("storage_full: the database") for p in health.json()["problems"])
        r = client.get(f"/api/v1/axes/{axis_id}/status", headers=hdr(keys["read"]))
        assert r.status_code == 503, r.text  # a request that needs the database: 503, never a 500
        full.clear()  # room again
        assert _wait(lambda: svc.waiting_for_room is None and svc.scheduler is not None, 30)
        svc.health.invalidate()
        assert client.get("/healthz").status_code == 200
        assert client.get(f"/api/v1/axes/{axis_id}/status", headers=hdr(keys["read"])).status_code == 200
    assert runner.calls == 0


def _cycle_on_full_disk(client, svc, runner, keys, axis_id, filler) -> tuple[str, int]:
    """A manual cycle that finishes after the disk was filled again to the last byte."""
    runner.gate.clear()
    r = client.post(f"/api/v1/axes/{axis_id}/measurements", headers=hdr(keys["operate"]))
    assert r.status_code in (200, 201, 202), r.text
    assert runner.running.wait(30)
    _fill_again(filler)
    runner.gate.set()
    assert svc.scheduler.idle(60)
    return r.json()["uuid"], r.json()["measurement"]["id"]


def test_the_second_third_and_fourth_full_disk_in_a_row_keep_their_cycles_or_their_record_across_kills(
        small_disk):
    """The reserve is spent by the first full disk; the second and the third (after a
    restart on the still full disk) are written into the two spool slots; the fourth finds
    no slot: its record goes to the loss ledger. No stop hook runs (as after kill -9): what
    survives is what is on disk. The restart with room stores the three measurements and
    records the fourth as lost, and says so."""
    data, first, seen, settings, keys, axis_id, filler = _finish_on_full_disk(small_disk, database_full=True)
    assert seen["spooled_after_stop"]
    real_save = results_repo.save_finished_cycle

    def refuse(s, fc):  # SQLite under the data folder finds no page
        raise DatabaseUnavailableError("database unavailable: database or disk is full")

    kept = [first]
    ids = [i["id"] for i in seen["items"]]
    try:
        for restart in (1, 2, 3):
            results_repo.save_finished_cycle = refuse
            runner = FakeRunner()
            runner.gate = threading.Event()
            runner.gate_timeout_s = 60.0
            app = create_app(replace(settings, spool_retry_s=3600.0), runner=runner)
            with TestClient(app) as client:
                svc = app.state.service
                # every cycle not stored yet is reported at the start, with its reason
                assert len(svc.report.not_stored) == len(kept) and svc.report.interrupted == 0
                for uuid in kept:
                    (line,) = [ln for ln in svc.report.not_stored if uuid in ln]
                    assert "storage_full" in line
                slots_before = svc.executor.free_slots()
                assert slots_before == max(3 - restart, 0)  # (2 slots; the reserve is spent)
                uuid, mid = _cycle_on_full_disk(client, svc, runner, keys, axis_id, filler)
                spooled = svc.executor.spool_dir / f"{uuid}.json"
                if restart < 3:
                    assert spooled.is_file() and svc.executor.unsaved == []  # on disk, not only in memory
                    assert svc.executor.free_slots() == slots_before - 1  # written into a slot
                    kept.append(uuid)
                else:  # no slot left: kept in memory, and its record in the loss ledger
                    assert not spooled.exists() and [fc.uuid for fc in svc.executor.unsaved] == [uuid]
                    assert uuid.encode() in (svc.executor.spool_dir / ".ledger").read_bytes()
                    lost = (uuid, mid)
                svc.health.invalidate()
                problems = client.get("/healthz").json()["problems"]
                left = "1 of 2 spool slot(s) keep the next cycles" if restart == 1 else "kept in memory only"
                assert any(left in p for p in problems), problems  # what the next full disk does, said
                (item,) = [i for i in client.get(f"/api/v1/axes/{axis_id}/measurements",
                                                 headers=hdr(keys["read"])).json()["items"] if i["id"] == mid]
                assert item["status"] != "running" and item["reason_code"] == "storage_full"
                ids.append(mid)
                svc.executor.flush_unsaved = lambda: 0  # killed: no stop hook writes anything
            assert not _empty_files(data)
    finally:
        results_repo.save_finished_cycle = real_save
    filler.unlink()  # room again: one restart stores all, re-analysed from their traces
    app = create_app(settings, runner=FakeRunner())
    with TestClient(app) as client:
        svc = app.state.service
        assert svc.report.replayed == 4 and svc.report.not_stored == () and svc.report.interrupted == 0
        (line,) = svc.report.lost
        assert lost[0] in line and "lost on a full disk" in line
        items = client.get(f"/api/v1/axes/{axis_id}/measurements", headers=hdr(keys["read"])).json()["items"]
        assert _wait(svc.executor.reserve_ok)  # the reserve, both slots and the ledger written again
        assert not svc.executor._ledger_records()  # the record was stored, its place freed
    by_id = {i["id"]: i for i in items}
    assert sorted(by_id) == sorted(ids)
    for mid in ids:
        if mid == lost[1]:  # recorded, counted as a lost raw run, never silently gone
            assert by_id[mid]["status"] == "failed" and by_id[mid]["reason_code"] == "storage_full"
            assert "lost" in by_id[mid]["failure_reason"] and by_id[mid]["raw_run_lost"]
        else:
            assert by_id[mid]["status"] == "ok" and by_id[mid]["reason_code"] == "storage_full"
            assert by_id[mid]["backlash_mean_um"] is not None
