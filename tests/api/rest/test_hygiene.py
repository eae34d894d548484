"""Hygiene: redaction, file modes, no-store on secrets, security headers, dates out of
range, plausibility limits naming the field, a revoked bootstrap key stays revoked,
demo keys in mode-600 files and printed only when created and asked for, Swagger UI without a CDN."""

from __future__ import annotations

import logging
from dataclasses import replace
from pathlib import Path

import pytest

from api.cli.serve import banner
from api.service.service import Service, redact_secrets
from storage.db import config_repo, session_scope
from tests.api.rest.conftest import FakeRunner, hdr, make_settings

V1 = "/api/v1"


@pytest.mark.parametrize("url", [
    "postgresql://mebm:s3cret@db/mebm",
    "postgresql://mebm@db/mebm?password=s3cret",
    "postgresql://mebm@db/mebm?sslmode=require&sslpassword=s3cret",
    "postgresql://mebm@db/mebm#password=s3cret",
    "postgresql+psycopg://mebm:s3cret@db:5432/mebm?application_name=x&PASSWORD=s3cret",
])
def test_passwords_are_redacted_in_every_part_of_a_url(url):
    out = redact_secrets(url)
    assert "s3cret" not in out and "***" in out and "db" in out and out.startswith(url.split("://")[0])


def test_a_url_without_secrets_is_left_as_it_is():
    assert redact_secrets("postgresql://mebm@db:5432/mebm?sslmode=require") == "postgresql://mebm@db:5432/mebm?sslmode=require"


@pytest.mark.parametrize("url", ["sqlite:////var/lib/mebm/mebm.sqlite3", "sqlite:///relative.sqlite3", "sqlite://"])
def test_a_sqlite_url_is_shown_as_written_with_its_slashes(url):
    # the banner's database line: one slash lost turns a path into a host name
    assert redact_secrets(url) == url


def test_data_folder_is_0700_and_the_database_0600(tmp_path):
    data = tmp_path / "data"
    data.mkdir(mode=0o755)
    svc = Service(make_settings(f"sqlite:///{data}/mebm.sqlite3", data), runner=FakeRunner())
    report = svc.start()
    try:
        assert report.database == f"sqlite:///{data}/mebm.sqlite3"  # the banner's line, an absolute path
        assert data.stat().st_mode & 0o777 == 0o700
        assert (data / "mebm.sqlite3").stat().st_mode & 0o777 == 0o600
        wal = data / "mebm.sqlite3-wal"
        assert not wal.exists() or wal.stat().st_mode & 0o077 == 0
    finally:
        svc.stop()


def test_a_created_key_is_not_cached_and_every_answer_has_security_headers(app_env):
    client, svc, keys, axis_id = app_env
    r = client.post(f"{V1}/keys", json={"name": "mes-2", "role": "read"}, headers=hdr(keys["admin"]))
    assert r.status_code == 201 and r.headers["cache-control"] == "no-store"
    client.get(f"{V1}/axes/{axis_id}/status", headers=hdr(keys["read"]))  # the second call takes the fast path
    for resp in (r, client.get("/healthz"), client.get(f"{V1}/machines"),
                 client.get(f"{V1}/axes/{axis_id}/status", headers=hdr(keys["read"]))):
        assert resp.headers["x-content-type-options"] == "nosniff"
        assert resp.headers["x-frame-options"] == "DENY"
        assert resp.headers["referrer-policy"] == "no-referrer"
        assert "frame-ancestors 'none'" in resp.headers["content-security-policy"]


def test_swagger_ui_is_served_from_the_package_without_a_cdn(client):
    page = client.get("/docs")
    assert page.status_code == 200
    assert "cdn" not in page.text.lower() and "https://" not in page.text
    assert client.get("/docs/assets/swagger-ui-bundle.js").status_code == 200
    assert client.get("/docs/assets/swagger-ui.css").status_code == 200


@pytest.mark.parametrize("param", ["since", "until"])
def test_a_date_out_of_range_is_a_422_naming_the_parameter(app_env, param):
    client, _svc, keys, axis_id = app_env
    for path in (f"{V1}/axes/{axis_id}/trend", f"{V1}/axes/{axis_id}/measurements"):
        r = client.get(path, params={param: "9999-12-31T23:59:59-23:59"}, headers=hdr(keys["read"]))
        assert r.status_code == 422 and param in r.json()["detail"], r.text


def _axis_body(**kw):
    body = {"name": "x", "transmission_mm_per_rev": 6.857, "screw_lead_mm": 16, "position_gain_per_s": 10,
            "travel_mm": [0, 500], "controller_url": "modbus://10.0.0.5:502", "measure_feed_mm_min": 2000}
    body.update(kw)
    return body


@pytest.mark.parametrize(("change", "field"), [
    ({"travel_mm": [-999999, 999999], "measure_feed_mm_min": 0.1}, "travel_mm"),
    ({"travel_mm": [0, 1000], "measure_feed_mm_min": 1}, "measure_feed_mm_min"),
    ({"tasks": [{"name": "   ", "profile": "circle", "radius_mm": 10, "feed_mm_min": 200, "tolerance_um": 20}]},
     "tasks.0.name"),
    ({"controller_url": "modbus://169.254.169.254:502"}, "controller_url"),
])
def test_implausible_axes_are_refused_naming_the_field(app_env, change, field):
    client, _svc, keys, _axis_id = app_env
    machine = client.get(f"{V1}/machines", headers=hdr(keys["read"])).json()[0]["id"]
    r = client.post(f"{V1}/machines/{machine}/axes", json=_axis_body(**change), headers=hdr(keys["admin"]))
    assert r.status_code == 422 and field in r.json()["detail"], r.text


def test_a_link_local_controller_is_accepted_when_the_configuration_allows_it(app_env):
    client, svc, keys, _axis_id = app_env
    svc.settings = replace(svc.settings, limits=replace(svc.settings.limits, allow_link_local_controllers=True))
    machine = client.get(f"{V1}/machines", headers=hdr(keys["read"])).json()[0]["id"]
    body = _axis_body(controller_url="modbus://169.254.10.20:502")
    assert client.post(f"{V1}/machines/{machine}/axes", json=body, headers=hdr(keys["admin"])).status_code == 201


def test_a_blank_key_name_is_refused(app_env):
    client, _svc, keys, _ = app_env
    r = client.post(f"{V1}/keys", json={"name": "  ", "role": "read"}, headers=hdr(keys["admin"]))
    assert r.status_code == 422 and "name" in r.json()["detail"]


def test_a_revoked_bootstrap_key_stays_revoked_and_start_up_goes_on(engine, db_url, tmp_path, caplog):
    secret = "bootstrap-" + "z" * 30
    settings = replace(make_settings(db_url, tmp_path), bootstrap_admin_key=secret, scheduler_enabled=False)
    svc = Service(settings, runner=FakeRunner())
    assert svc.start().bootstrap_admin == "bootstrap-admin"
    with session_scope(svc.factory) as s:
        config_repo.revoke_key(s, config_repo.find_key(s, "bootstrap-admin").id)
    svc.stop()
    again = Service(settings, runner=FakeRunner())
    with caplog.at_level(logging.WARNING, logger="mebm.service"):
        report = again.start()  # no "this key is registered already"
    try:
        assert report.bootstrap_admin is None
        with session_scope(again.factory) as s:
            assert config_repo.authenticate(s, secret) is None
        assert any("revoked" in r.getMessage() for r in caplog.records)
        assert not any(secret in r.getMessage() for r in caplog.records)
    finally:
        again.stop()


def _demo_settings(db_url, tmp_path):
    base = make_settings(db_url, tmp_path)
    return replace(base, demo_keys=True, scheduler_enabled=False,
                   axes=(replace(base.axes[0], settings=replace(base.axes[0].settings, controller_url="sim")),))


def test_demo_keys_go_to_mode_600_files_and_stdout_prints_them_only_with_show_keys(engine, db_url, tmp_path):
    demo = _demo_settings(db_url, tmp_path)
    first = Service(demo, runner=FakeRunner())
    created = first.start()
    first.stop()
    assert set(created.demo_keys) == {"read", "operate", "admin"}
    quiet = banner(demo, created, "http://127.0.0.1:1")
    assert not any(k in quiet for k in created.demo_keys.values())
    assert str(tmp_path / "demo-keys.json") in quiet and str(tmp_path / "admin-key") in quiet
    assert "--show-keys" in quiet and '"X-API-Key: $K"' in quiet
    shown = banner(demo, created, "http://127.0.0.1:1", show_keys=True)
    assert all(k in shown for k in created.demo_keys.values())
    link, link_file = "http://127.0.0.1:1/ui/sign-in/tok3n", tmp_path / "sign-in-link"
    assert "tok3n" not in banner(demo, created, "u", sign_in_url=link, sign_in_file=link_file)
    assert str(link_file) in banner(demo, created, "u", sign_in_url=link, sign_in_file=link_file)
    assert link in banner(demo, created, "u", sign_in_url=link, sign_in_file=link_file, show_keys=True)
    kept = (tmp_path / "demo-keys.json").read_text()
    assert created.demo_keys["admin"] not in kept and created.demo_keys["read"] in kept
    assert (tmp_path / "admin-key").read_text().strip() == created.demo_keys["admin"]
    for name in ("demo-keys.json", "admin-key"):
        assert (tmp_path / name).stat().st_mode & 0o777 == 0o600
    again = Service(demo, runner=FakeRunner())
    report = again.start()
    try:
        assert report.demo_keys == {}
        text = banner(demo, report, "http://127.0.0.1:1", show_keys=True)
        assert not any(k in text for k in created.demo_keys.values())  # created before: never printed again
        assert f"the demo admin key is in {tmp_path / 'admin-key'}" in text
        with session_scope(again.factory) as s:
            assert config_repo.authenticate(s, created.demo_keys["admin"]).role == "admin"
        (tmp_path / "admin-key").unlink()  # the operator took it away
        assert "admin-key" not in banner(demo, report, "http://127.0.0.1:1")
        assert (tmp_path / "admin-key").exists() is False
    finally:
        again.stop()


def test_demo_keys_whose_files_cannot_be_written_are_not_created_and_the_next_start_creates_them(
        engine, db_url, tmp_path, monkeypatch):
    import errno

    import api.service.service as service_module

    demo = _demo_settings(db_url, tmp_path)
    real = service_module.write_secret_file

    def full(path, text):
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(service_module, "write_secret_file", full)
    first = Service(demo, runner=FakeRunner())
    report = first.start()  # a full disk does not stop the start
    try:
        assert report.demo_keys == {}
        with session_scope(first.factory) as s:
            assert not [k for k in config_repo.list_keys(s) if k.name.startswith("demo-")]  # no key nobody holds
    finally:
        first.stop()
    monkeypatch.setattr(service_module, "write_secret_file", real)
    again = Service(demo, runner=FakeRunner())
    try:
        assert set(again.start().demo_keys) == {"read", "operate", "admin"}
        assert (tmp_path / "admin-key").is_file()
    finally:
        again.stop()


def test_a_secret_file_is_created_exclusively_mode_600_and_replaces_a_planted_link(tmp_path, monkeypatch):
    import os

    from api.service import secret_files

    opened = []
    real_open = os.open

    def spy(path, flags, mode=0o777, *a, **k):
        opened.append((Path(path), flags, mode))
        return real_open(path, flags, mode, *a, **k)

    elsewhere = tmp_path / "elsewhere"
    elsewhere.write_text("untouched")
    target = tmp_path / "admin-key"
    target.symlink_to(elsewhere)  # planted: the secret must not be written through it
    monkeypatch.setattr(secret_files.os, "open", spy)
    old_umask = os.umask(0)  # even a permissive umask gives no other user a look
    try:
        secret_files.write_secret_file(target, "mebm_secret\n")
    finally:
        os.umask(old_umask)
    ((path, flags, mode),) = opened
    assert path.parent == tmp_path and path != target  # a fresh name, renamed over the target
    assert flags & os.O_CREAT and flags & os.O_EXCL and mode == 0o600  # mode 600 from its first byte
    assert not target.is_symlink() and target.read_text() == "mebm_secret\n"
    assert target.stat().st_mode & 0o777 == 0o600
    assert elsewhere.read_text() == "untouched"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["admin-key", "elsewhere"]  # no temporary file left
