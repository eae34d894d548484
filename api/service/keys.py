"""The verified access keys of one process, kept ``ttl_s`` (1 s) so a busy client does not
cost a database round trip per request; one cache for every interface that takes keys
(the REST API, the dashboard, the MTConnect agent).

Revocation, the one figure that holds everywhere: a key revoked through this process (the
API's ``DELETE /keys/{id}`` or the dashboard) is refused by all of its interfaces as soon
as the revocation has answered; one revoked by another process of the same database
(another fleet worker or ``mebm serve``, ``mebm keys revoke``) within ``ttl_s``. The
revoking code clears the cache *after* its transaction committed (:meth:`KeyCache.clear`),
and a look-up that read the database before that clear does not store what it read (the
cache's generation changed meanwhile), so no stale "valid" can outlive the clear.
"""

from __future__ import annotations

import threading
import time

from storage.db import KeyRecord, config_repo, session_scope

KEY_CACHE_TTL_S = 1.0


class KeyCache:
    """Keys as looked up in the database, each kept ``ttl_s`` (see the module docstring)."""

    def __init__(self, ttl_s: float = KEY_CACHE_TTL_S, clock=time.monotonic):
        self.ttl_s = ttl_s
        self.clock = clock
        self._d: dict[str, tuple[float, KeyRecord | None]] = {}
        self._lock = threading.Lock()
        self._generation = 0  # bumped by clear(): a look-up begun before it stores nothing

    def cached(self, secret: str) -> tuple[bool, KeyRecord | None]:
        hit = self._d.get(secret)
        if hit is not None and self.clock() - hit[0] < self.ttl_s:
            return True, hit[1]
        return False, None

    def lookup(self, factory, secret: str) -> KeyRecord | None:
        now = self.clock()
        found, rec = self.cached(secret)
        if found:
            return rec
        generation = self._generation
        with session_scope(factory) as s:
            rec = config_repo.authenticate(s, secret)
        with self._lock:
            if generation == self._generation:  # no revocation committed since the read began
                if len(self._d) > 10000:
                    self._d.clear()
                self._d[secret] = (now, rec)
        return rec

    def clear(self) -> None:
        """Forget every key: call it after the transaction that revoked a key committed."""
        with self._lock:
            self._generation += 1
            self._d.clear()
