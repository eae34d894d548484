"""The failed-authentication throttle refuses failures, never a valid key; it counts per
client address and presented key prefix and per address; and the client address is the
TCP peer unless that peer is a configured trusted proxy (a real uvicorn server, started
with ``mebm serve``'s configuration, and a real HTTP client)."""

from __future__ import annotations

import httpx
import pytest

from api.service.config.loading import parse_settings
from api.service.config.settings import ConfigError, LimitSettings
from api.service.throttle import AuthThrottle
from storage.db import config_repo, session_scope
from tests.api.rest.conftest import ServedApp, hdr

V1 = "/api/v1"


def test_a_valid_key_is_admitted_after_many_failures_from_its_address(app_env):
    client, _, keys, _ = app_env
    codes = [client.get(f"{V1}/machines", headers=hdr("wrong-" + "k" * 40)).status_code for _ in range(30)]
    assert codes[:20] == [401] * 20 and codes[20:] == [429] * 10
    assert client.get(f"{V1}/machines", headers=hdr(keys["admin"])).status_code == 200
    assert client.get(f"{V1}/keys", headers=hdr(keys["admin"])).status_code == 200


def test_one_repeated_wrong_key_does_not_use_up_the_others_failures(app_env):
    client, _, _, _ = app_env
    stale = [client.get(f"{V1}/machines", headers=hdr("stale-script-key-0001")).status_code for _ in range(25)]
    assert stale[-1] == 429
    other = client.get(f"{V1}/machines", headers=hdr("typo-of-a-key-000001"))
    assert other.status_code == 401 and "unknown or revoked" in other.json()["detail"]


def test_many_different_wrong_keys_from_one_address_are_throttled(app_env):
    client, _, keys, _ = app_env
    client.app.state.auth_throttle = AuthThrottle(1.0, 20, 1.0, 5)
    codes = [client.get(f"{V1}/machines", headers=hdr(f"guess-{i:04d}-xxxxxxxxxx")).status_code for i in range(7)]
    assert codes == [401] * 5 + [429] * 2
    assert client.get(f"{V1}/machines", headers=hdr(keys["read"])).status_code == 200


def test_a_throttled_run_is_logged_once():
    now = [0.0]
    t = AuthThrottle(1.0, 2, 60.0, 100, clock=lambda: now[0])
    assert [t.failed("10.0.0.1", "abcdefghijXYZ") for _ in range(4)] == [
        (0.0, False), (0.0, False), (pytest.approx(60.0), True), (pytest.approx(60.0), False)]
    assert t.failed("10.0.0.1", "abcdefghijOTHER")[0] > 0  # the same first characters: one bucket
    assert t.failed("10.0.0.2", "abcdefghijXYZ") == (0.0, False)
    now[0] = 60.0
    assert t.failed("10.0.0.1", "abcdefghijXYZ") == (0.0, False)
    assert t.failed("10.0.0.1", "abcdefghijXYZ") == (pytest.approx(60.0), True)  # a new run


@pytest.mark.parametrize("value", [["*"], ["proxy.example.com"], "127.0.0.1", [1]])
def test_trusted_proxies_are_addresses_or_networks(value):
    with pytest.raises(ConfigError, match="server.trusted_proxies"):
        parse_settings({"server": {"trusted_proxies": value}})
    assert parse_settings({"server": {"trusted_proxies": ["127.0.0.1", "10.0.0.0/8", "::1"]}}).trusted_proxies \
        == ("127.0.0.1", "10.0.0.0/8", "::1")
    assert parse_settings({}).trusted_proxies == ()


@pytest.fixture
def served(tmp_path, request):
    s = ServedApp(tmp_path, limits=LimitSettings(auth_failure_burst=1), **getattr(request, "param", {}))
    yield s
    s.close()


def _two_failures(url: str) -> httpx.Response:
    with httpx.Client(base_url=url, timeout=30) as c:
        forged = {"X-API-Key": "wrong-key-0000000000", "X-Forwarded-For": "10.9.9.9"}
        assert c.get(f"{V1}/machines", headers=forged).status_code == 401
        return c.get(f"{V1}/machines", headers=forged)


def test_a_forged_forwarded_for_from_an_untrusted_peer_is_ignored(served, caplog):
    with caplog.at_level("WARNING", logger="mebm.api"):
        r = _two_failures(served.url)
    assert r.status_code == 429 and "from 127.0.0.1;" in r.json()["detail"]
    lines = [m.getMessage() for m in caplog.records if "throttled" in m.getMessage()]
    assert lines == [lines[0]] and "from 127.0.0.1 (X-Forwarded-For '10.9.9.9')" in lines[0]
    with session_scope(served.app.state.service.factory) as s:
        key = config_repo.create_key(s, "reader", "read")[1]
    assert httpx.get(f"{served.url}{V1}/machines", headers=hdr(key), timeout=30).status_code == 200


@pytest.mark.parametrize("served", [{"trusted_proxies": ("127.0.0.1",)}], indirect=True)
def test_forwarded_for_from_a_trusted_proxy_names_the_client(served, caplog):
    with caplog.at_level("WARNING", logger="mebm.api"):
        r = _two_failures(served.url)
    assert r.status_code == 429 and "from 10.9.9.9;" in r.json()["detail"]
    lines = [m.getMessage() for m in caplog.records if "throttled" in m.getMessage()]
    assert "from 10.9.9.9 via peer 127.0.0.1 (X-Forwarded-For '10.9.9.9')" in lines[0]
    # the proxy's own address has used none of its budget
    with httpx.Client(base_url=served.url, timeout=30) as c:
        assert c.get(f"{V1}/machines", headers={"X-API-Key": "wrong-key-0000000000"}).status_code == 401


def test_a_run_of_refusals_is_reported_once_per_window_with_its_count():
    now = [0.0]
    t = AuthThrottle(0.1, 1, 60.0, 100, clock=lambda: now[0], report_window_s=60.0)  # refills in 600 s
    assert t.failed("10.0.0.1", "abcdefghijXYZ") == (0.0, False)  # admitted: logged by the caller
    assert t.failed("10.0.0.1", "abcdefghijXYZ")[1] is True  # the run starts: one line
    for i in range(500):  # a flood within the window: counted, no line each
        now[0] = 0.1 * i
        assert t.failed("10.0.0.1", "abcdefghijXYZ")[1] is False
        assert t.reports() == []
    now[0] = 60.0
    t.failed("10.0.0.1", "abcdefghijXYZ")
    assert t.reports() == [("10.0.0.1", 501, pytest.approx(60.0))]  # once, with the count
    now[0] = 70.0
    t.failed("10.0.0.1", "abcdefghijXYZ")
    t.failed("10.0.0.1", "abcdefghijXYZ")
    assert t.reports() == []
    assert t.flush() == [("10.0.0.1", 2, pytest.approx(10.0))]  # the rest, when the service stops
    assert t.flush() == []


def test_a_flood_of_refused_failures_is_a_few_log_lines_and_every_refusal_is_counted(tmp_path, caplog):
    from fastapi.testclient import TestClient

    from api.rest import create_app
    from tests.api.rest.conftest import FakeRunner, make_settings

    app = create_app(make_settings(f"sqlite:///{tmp_path}/m.sqlite3", tmp_path, scheduler_enabled=False),
                     runner=FakeRunner())
    app.state.auth_throttle = AuthThrottle(1.0, 2, 60.0, 1000)  # one report window: the whole test
    wrong = "flood-" + "k" * 40
    with caplog.at_level("WARNING", logger="mebm.api"):
        with TestClient(app) as client:
            codes = [client.get(f"{V1}/machines", headers=hdr(wrong)).status_code for _ in range(40)]
            during = [r.getMessage() for r in caplog.records if "failed authentication" in r.getMessage()]
        after = [r.getMessage() for r in caplog.records if "failed authentication" in r.getMessage()]
    assert codes == [401] * 2 + [429] * 38
    assert len(during) == 3 and "throttled for" in during[2]  # two admitted, the run's start: not one per failure
    assert after[3:] == ["37 more failed authentications from testclient refused (throttled) in the last "
                         + after[3].rsplit("last ", 1)[1]]  # the rest, counted, when the service stops
    assert not any(wrong in r.getMessage() for r in caplog.records)
