"""Revocation holds on every interface of the process that revoked the key as soon as the
revocation has answered (REST, MTConnect with require_key, the dashboard share one key
cache), and a look-up that read the database before the revocation committed cannot put
the key back in the cache. OPC UA takes no API keys (its users are configured in
[opcua]), so no key revocation concerns it. Other processes: tests/api/rest/test_key_cache.py."""

from __future__ import annotations

import threading

from fastapi.testclient import TestClient

from api.rest import create_app
from api.service.config.settings import MtconnectSettings
from api.service.keys import KeyCache
from storage.db import config_repo, session_scope
from tests.api.rest.conftest import FakeRunner, hdr, make_settings

V1 = "/api/v1"


def _app(tmp_path):
    settings = make_settings(f"sqlite:///{tmp_path}/db.sqlite3", tmp_path,
                             mtconnect=MtconnectSettings(require_key=True))
    return create_app(settings, runner=FakeRunner())


def _keys(app) -> tuple[str, int, str]:
    with session_scope(app.state.service.factory) as s:
        admin = config_repo.create_key(s, "admin", "admin")[1]
        rec, secret = config_repo.create_key(s, "mes", "read")
    return admin, rec.id, secret


def test_a_key_revoked_through_the_api_is_refused_by_rest_and_mtconnect_right_after_the_delete(tmp_path):
    app = _app(tmp_path)
    with TestClient(app) as client:
        admin, key_id, secret = _keys(app)
        assert client.get(f"{V1}/machines", headers=hdr(secret)).status_code == 200
        assert client.get("/mtconnect/current", headers=hdr(secret)).status_code == 200  # both cache it now
        cache = app.state.key_cache
        real_clear = cache.clear

        def clear_then_a_request_arrives():  # a request of the key's client between the clear and the answer
            real_clear()
            cache.lookup(app.state.service.factory, secret)

        cache.clear = clear_then_a_request_arrives
        assert client.delete(f"{V1}/keys/{key_id}", headers=hdr(admin)).status_code == 200
        assert client.get("/mtconnect/current", headers=hdr(secret)).status_code == 401
        assert client.get(f"{V1}/machines", headers=hdr(secret)).status_code == 401
        assert client.get(f"{V1}/alerts", headers={"Authorization": f"Bearer {secret}"}).status_code == 401


def test_a_look_up_that_read_the_key_before_the_revocation_does_not_cache_it(tmp_path):
    app = _app(tmp_path)
    with TestClient(app):
        _, key_id, secret = _keys(app)
        factory = app.state.service.factory
        cache = KeyCache()
        read, go_on = threading.Event(), threading.Event()
        real = config_repo.authenticate
        seen = []

        def slow_authenticate(s, key):
            rec = real(s, key)  # read while the key is valid...
            read.set()
            assert go_on.wait(30)  # ...and stored only after the revocation committed and cleared
            return rec

        config_repo.authenticate = slow_authenticate
        try:
            t = threading.Thread(target=lambda: seen.append(cache.lookup(factory, secret)))
            t.start()
            assert read.wait(30)
            with session_scope(factory) as s:
                config_repo.revoke_key(s, key_id)
            cache.clear()
            go_on.set()
            t.join(30)
        finally:
            config_repo.authenticate = real
        assert seen and seen[0] is not None  # the look-up that raced the revocation answered what it read
        assert cache.cached(secret) == (False, None)  # but did not keep it
        assert cache.lookup(factory, secret) is None  # the next one reads the revocation


def test_the_dashboard_the_rest_api_and_mtconnect_share_one_key_cache(tmp_path):
    app = _app(tmp_path)
    with TestClient(app) as client:
        _, _, secret = _keys(app)
        assert client.get("/mtconnect/probe", headers=hdr(secret)).status_code == 200
        found, rec = app.state.key_cache.cached(secret)  # the agent's look-up is the API's cache entry
        assert found and rec is not None and rec.name == "mes"


def test_opc_ua_takes_no_api_key_so_no_key_revocation_concerns_it(tmp_path):
    from api.opcua.access import Users
    from api.service.config.settings import OpcuaSettings

    app = _app(tmp_path)
    with TestClient(app):
        _, _, secret = _keys(app)
    users = Users(OpcuaSettings(anonymous=False, username="plant", password="configured-in-opcua"))
    # a valid API key is no OPC UA credential, under any user name: OPC UA users are [opcua]'s
    assert users.get_user(None, username="mes", password=secret) is None
    assert users.get_user(None, username="plant", password=secret) is None
    assert users.get_user(None, username="plant", password="configured-in-opcua") is not None
