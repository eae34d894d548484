"""A key revoked by another process (another worker of a fleet, the CLI on the same
database) stops working once its cache entry is older than the cache's time to live,
1 s by default; one revoked through this process's API stops at once. The cache's clock
is injected: the test turns it, it does not wait."""

from __future__ import annotations

from api.rest.auth import KeyCache
from storage.db import config_repo, session_scope
from tests.api.rest.conftest import hdr
from tests.clock import ManualClock

V1 = "/api/v1"


def test_a_key_revoked_in_the_database_is_refused_after_one_second_of_cache(app_env):
    client, svc, keys, _ = app_env
    assert KeyCache().ttl_s == 1.0
    clock = ManualClock(1000.0)
    client.app.state.key_cache = cache = KeyCache(clock=clock)
    with session_scope(svc.factory) as s:
        rec, secret = config_repo.create_key(s, "mes-2", "read")
    assert client.get(f"{V1}/machines", headers=hdr(secret)).status_code == 200
    with session_scope(svc.factory) as s:  # as another process would: straight in the database
        config_repo.revoke_key(s, rec.id)
    clock.t += 0.9
    assert client.get(f"{V1}/machines", headers=hdr(secret)).status_code == 200  # still cached
    clock.t += 0.2
    assert client.get(f"{V1}/machines", headers=hdr(secret)).status_code == 401
    assert cache.cached(secret) == (True, None)  # the refusal is cached as well


def test_a_key_revoked_through_the_api_is_refused_at_once(app_env):
    client, svc, keys, _ = app_env
    clock = ManualClock(1000.0)
    client.app.state.key_cache = KeyCache(clock=clock)
    with session_scope(svc.factory) as s:
        rec, secret = config_repo.create_key(s, "mes-3", "read")
    assert client.get(f"{V1}/machines", headers=hdr(secret)).status_code == 200
    assert client.delete(f"{V1}/keys/{rec.id}", headers=hdr(keys["admin"])).status_code == 200
    assert client.get(f"{V1}/machines", headers=hdr(secret)).status_code == 401  # the clock did not move
