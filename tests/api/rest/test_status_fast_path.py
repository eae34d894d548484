"""The status poll's fast path answers exactly as the route does, and only when it may."""

from __future__ import annotations

import asyncio
import json

import pytest

from api.rest.status_body import STATUS_PATH, StatusFastPath
from tests.api.rest.conftest import hdr
from tests.api.rest.test_api import V1, run_cycle


def _ask(app, path: str, headers, query: bytes = b"") -> tuple[bool, bytes | None]:
    """Call the fast path alone (the rest of the stack replaced by a marker): (fell through, body)."""
    fell = []

    async def rest(scope, receive, send):
        fell.append(True)

    sent = []

    async def send(msg):
        sent.append(msg)

    pairs = headers.items() if isinstance(headers, dict) else headers
    scope = {"type": "http", "method": "GET", "path": path, "query_string": query,
             "headers": [(k.lower().encode(), v.encode()) for k, v in pairs]}
    asyncio.run(StatusFastPath(rest, app.state)(scope, None, send))
    if fell:
        return True, None
    assert sent[0]["status"] == 200 and (b"content-type", b"application/json") in sent[0]["headers"]
    return False, sent[1]["body"]


def test_fast_path_body_equals_the_route_body(app_env, runner):
    client, svc, keys, axis_id = app_env
    runner.backlash_um = 240.0  # past the 236 µm limit: ALARM, with an alert and a reduction
    run_cycle(client, svc, keys, axis_id)
    path = f"{V1}/axes/{axis_id}/status"
    via_stack = client.get(path, headers=hdr(keys["read"]))  # verifies the key, computes the status
    assert via_stack.status_code == 200
    fell, body = _ask(client.app, path, hdr(keys["read"]))
    assert not fell
    a, b = via_stack.json(), json.loads(body)
    assert abs(a.pop("age_s") - b.pop("age_s")) < 5.0
    assert a == b
    assert b["state"] == "ALARM" and b["active_alert_id"] is not None
    # and the route itself (bypassing the fast path) renders the same
    route_body = client.get(path + "?via=route", headers=hdr(keys["read"])).json()
    route_body.pop("age_s")
    assert route_body == a


@pytest.mark.parametrize("case", ["no key", "unknown key", "not yet verified", "uncached axis", "too large id",
                                  "leading zero", "query string", "bearer"])
def test_fast_path_falls_through_unless_key_and_status_are_cached(app_env, case):
    client, svc, keys, axis_id = app_env
    path = f"{V1}/axes/{axis_id}/status"
    if case != "not yet verified":
        assert client.get(path, headers=hdr(keys["read"])).status_code == 200  # key and status now cached
    expect_fall = True
    headers, query = hdr(keys["read"]), b""
    if case == "no key":
        headers = {}
    elif case == "unknown key":
        headers = hdr("mebm_not-a-key")
    elif case == "uncached axis":
        path = f"{V1}/axes/{axis_id + 1}/status"
    elif case == "too large id":
        path = f"{V1}/axes/{2**31}/status"
    elif case == "leading zero":
        path = f"{V1}/axes/0{axis_id}/status"
    elif case == "query string":
        query = b"x=1"
    elif case == "bearer":
        headers, expect_fall = {"Authorization": f"Bearer {keys['read']}"}, False
    assert _ask(client.app, path, headers, query)[0] is expect_fall
    # whatever the fast path did, the full stack answers these as before
    r = client.get(path + ("?" + query.decode() if query else ""), headers=headers)
    assert r.status_code == {"no key": 401, "unknown key": 401, "uncached axis": 404, "too large id": 422,
                             "leading zero": 200, "query string": 200, "bearer": 200,
                             "not yet verified": 200}[case], r.text


def test_a_revoked_key_is_no_longer_served_by_the_fast_path(app_env):
    client, svc, keys, axis_id = app_env
    path = f"{V1}/axes/{axis_id}/status"
    assert client.get(path, headers=hdr(keys["read"])).status_code == 200
    assert _ask(client.app, path, hdr(keys["read"]))[0] is False
    ids = {k["name"]: k["id"] for k in client.get(f"{V1}/keys", headers=hdr(keys["admin"])).json()}
    assert client.delete(f"{V1}/keys/{ids['test-read']}", headers=hdr(keys["admin"])).status_code == 200
    assert _ask(client.app, path, hdr(keys["read"]))[0] is True
    assert client.get(path, headers=hdr(keys["read"])).status_code == 401


def test_status_path_pattern():
    assert STATUS_PATH.fullmatch("/api/v1/axes/12/status").group(1) == "12"
    for bad in ("/api/v1/axes/0/status", "/api/v1/axes/-1/status", "/api/v1/axes/1/status/", "/api/v1/axes/x/status"):
        assert STATUS_PATH.fullmatch(bad) is None


def test_a_repeated_key_header_is_read_as_the_route_reads_it(app_env):
    # the first X-API-Key counts on both paths: an unknown first key is a 401 even when a
    # valid one follows
    client, svc, keys, axis_id = app_env
    path = f"{V1}/axes/{axis_id}/status"
    assert client.get(path, headers=hdr(keys["read"])).status_code == 200
    twice = [("X-API-Key", "mebm_not-a-key"), ("X-API-Key", keys["read"])]
    assert _ask(client.app, path, twice)[0] is True
    assert client.get(path, headers=twice).status_code == 401
    assert _ask(client.app, path, list(reversed(twice)))[0] is False
