"""/healthz and /metrics tell the truth: a database that cannot be written, a data
folder that cannot be written and free disk below the floor are each `degraded`, with
the reason. Tests run as root, for whom chmod makes nothing unwritable, so each fault
is a real one: a read-only database connection (SQLite ``PRAGMA query_only``,
PostgreSQL ``default_transaction_read_only``), a folder whose parent is a regular file,
and a floor above the disk's actual free space."""

from __future__ import annotations

from dataclasses import replace

from sqlalchemy import event

from storage.db import make_engine, make_session_factory
from tests.api.rest.conftest import hdr


def _fresh(client):
    client.app.state.service.health.invalidate()
    r = client.get("/healthz")
    return r.status_code, r.json()


def test_healthy_service_says_ok(app_env):
    client, svc, keys, _ = app_env
    code, body = _fresh(client)
    assert code == 200 and body["status"] == "ok" and body["problems"] == []
    assert body["database"] == "ok" and body["data_dir"] == "ok" and body["free_disk_mb"] > 0
    text = client.get("/metrics", headers=hdr(keys["read"])).text
    assert "mebm_healthy 1.0" in text and "mebm_database_writable 1.0" in text


def test_a_database_that_answers_but_refuses_writes_is_degraded(app_env, db_url):
    client, svc, keys, _ = app_env
    ro = make_engine(db_url)

    @event.listens_for(ro, "connect")
    def read_only(dbapi_conn, _record):
        cur = dbapi_conn.cursor()
        if ro.dialect.name == "sqlite":
            cur.execute("PRAGMA query_only=ON")
        else:
            cur.execute("SET default_transaction_read_only = on")
        cur.close()
        if ro.dialect.name != "sqlite":
            dbapi_conn.commit()

    real = svc.factory
    svc.factory = make_session_factory(ro)
    try:
        code, body = _fresh(client)
        text = client.get("/metrics", headers=hdr(keys["read"])).text
    finally:
        svc.factory = real
        ro.dispose()
    assert code == 503 and body["status"] == "degraded" and body["database"] == "read-only"
    assert any("database cannot be written" in p for p in body["problems"])
    assert "mebm_database_writable 0.0" in text and "mebm_healthy 0.0" in text
    assert 'mebm_degraded{reason="database cannot be written' in text


def test_a_data_folder_that_cannot_take_files_is_degraded(app_env, tmp_path):
    client, svc, keys, _ = app_env
    blocked = tmp_path / "a-file"
    blocked.write_text("a regular file where a folder's parent should be")
    real = svc.executor.datasets_dir
    svc.executor.datasets_dir = blocked / "datasets"
    try:
        code, body = _fresh(client)
        text = client.get("/metrics", headers=hdr(keys["read"])).text
    finally:
        svc.executor.datasets_dir = real
    assert code == 503 and body["data_dir"] == "not writable" and body["database"] == "ok"
    assert any(str(blocked / "datasets") in p for p in body["problems"])
    assert "mebm_data_dir_writable 0.0" in text


def test_free_disk_below_the_floor_is_degraded(app_env):
    client, svc, keys, _ = app_env
    real = svc.settings
    svc.settings = replace(real, min_free_disk_mb=1e12)  # a petabyte: more than this disk has free
    try:
        code, body = _fresh(client)
        text = client.get("/metrics", headers=hdr(keys["read"])).text
    finally:
        svc.settings = real
    assert code == 503 and any("below the floor" in p and "min_free_disk_mb" in p for p in body["problems"])
    assert "mebm_disk_free_floor_bytes 1e+18" in text
