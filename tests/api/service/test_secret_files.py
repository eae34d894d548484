"""Key files belong to one database: the first database that writes key files in a data
folder has the plain names (recorded in key-files.database), any other database's carry
its identity in the name, and demo-keys*.json names its database in a field. A data
folder used with a second database never overwrites the first's keys, and switching back
finds them again."""

from __future__ import annotations

import json
from dataclasses import replace

from api.cli.keys import key_file
from api.service.secret_files import OWNER_FILE, database_identity, secret_path
from api.service.service import Service
from storage.db import config_repo, session_scope
from tests.api.rest.conftest import FakeRunner, make_settings


def _demo(tmp_path, database_url):
    base = make_settings(database_url, tmp_path)
    return replace(base, database_url=database_url, demo_keys=True, scheduler_enabled=False,
                   axes=(replace(base.axes[0], settings=replace(base.axes[0].settings, controller_url="sim")),))


def _start(settings):
    svc = Service(settings, runner=FakeRunner())
    report = svc.start()
    return svc, report


def test_the_identity_of_a_database_ignores_its_password_and_names_an_sqlite_file_by_its_absolute_path(tmp_path):
    a = database_identity(tmp_path, "postgresql+psycopg://mebm:secret@db.local:5432/plant")
    assert a == database_identity(tmp_path, "postgresql+psycopg://mebm:other@db.local:5432/plant")
    assert "secret" not in a and a != database_identity(tmp_path, "postgresql+psycopg://mebm@db.local:5432/plant2")
    assert database_identity(tmp_path, None) == database_identity(tmp_path, f"sqlite:///{tmp_path}/mebm.sqlite3")
    # nobody's plain names yet: plain; the first claim makes them its own, the next database gets a tag
    assert secret_path(tmp_path, "postgresql://h/a", "admin-key") == tmp_path / "admin-key"
    assert secret_path(tmp_path, "postgresql://h/a", "admin-key", claim=True) == tmp_path / "admin-key"
    b = secret_path(tmp_path, "postgresql://h/b", "demo-keys.json", claim=True)
    assert b.parent == tmp_path and b.name.startswith("demo-keys.") and b.name.endswith(".json") and b.name != \
        "demo-keys.json"
    assert secret_path(tmp_path, "postgresql://h/b", "sign-in-link").name == "sign-in-link." + b.name.split(".")[1]
    assert key_file(tmp_path, 3, "postgresql://h/b").name == f"3.{b.name.split('.')[1]}.key"
    assert key_file(tmp_path, 3, "postgresql://h/a") == tmp_path / "keys" / "3.key"


def test_a_second_database_on_the_same_data_folder_writes_key_files_of_its_own_and_the_first_keeps_its_own(tmp_path):
    first_url, second_url = f"sqlite:///{tmp_path}/first.sqlite3", f"sqlite:///{tmp_path}/second.sqlite3"
    svc, first = _start(_demo(tmp_path, first_url))
    svc.stop()
    assert set(first.demo_keys) == {"read", "operate", "admin"}
    assert (tmp_path / OWNER_FILE).read_text().strip() == database_identity(tmp_path, first_url)
    first_keys = json.loads((tmp_path / "demo-keys.json").read_text())
    assert first_keys["database"] == database_identity(tmp_path, first_url)
    assert (tmp_path / "admin-key").read_text().strip() == first.demo_keys["admin"]

    svc, second = _start(_demo(tmp_path, second_url))  # a new database, the same data folder
    svc.stop()
    assert set(second.demo_keys) == {"read", "operate", "admin"}
    kept_at = secret_path(tmp_path, second_url, "demo-keys.json")
    admin_at = secret_path(tmp_path, second_url, "admin-key")
    assert kept_at != tmp_path / "demo-keys.json" and admin_at != tmp_path / "admin-key"
    second_keys = json.loads(kept_at.read_text())
    assert second_keys["database"] == database_identity(tmp_path, second_url)
    assert second_keys["read"] == second.demo_keys["read"] and admin_at.read_text().strip() == second.demo_keys["admin"]
    assert kept_at.stat().st_mode & 0o777 == 0o600 and admin_at.stat().st_mode & 0o777 == 0o600
    # the first database's files are untouched
    assert json.loads((tmp_path / "demo-keys.json").read_text()) == first_keys
    assert (tmp_path / "admin-key").read_text().strip() == first.demo_keys["admin"]

    svc, again = _start(_demo(tmp_path, first_url))  # back to the first: its keys, nothing new
    try:
        assert again.demo_keys == {}
        with session_scope(svc.factory) as s:
            assert config_repo.authenticate(s, first_keys["read"]) is not None
            assert config_repo.authenticate(s, second_keys["read"]) is None
    finally:
        svc.stop()


def test_a_key_file_of_another_database_under_the_plain_name_is_moved_aside_not_overwritten(tmp_path):
    # written before the files carried their database: no field, no owner recorded, keys of no database here
    (tmp_path / "demo-keys.json").write_text(json.dumps({"read": "mebm_elsewhere_r", "operate": "mebm_elsewhere_o"}))
    (tmp_path / "admin-key").write_text("mebm_elsewhere_admin\n")
    svc, report = _start(_demo(tmp_path, f"sqlite:///{tmp_path}/new.sqlite3"))
    svc.stop()
    assert set(report.demo_keys) == {"read", "operate", "admin"}
    aside = sorted(p.name for p in tmp_path.iterdir() if ".aside-" in p.name)
    assert [n.split(".aside-")[0] for n in aside] == ["admin-key", "demo-keys.json"]
    moved = {n.split(".aside-")[0]: (tmp_path / n).read_text() for n in aside}
    assert "mebm_elsewhere_r" in moved["demo-keys.json"] and moved["admin-key"] == "mebm_elsewhere_admin\n"
    assert json.loads((tmp_path / "demo-keys.json").read_text())["read"] == report.demo_keys["read"]
