"""API keys: ``X-API-Key: <key>`` (or ``Authorization: Bearer <key>``), roles
read < operate < admin. Keys are looked up by their SHA-256; a verified key is kept for
1 s (:class:`api.service.keys.KeyCache`, shared with the dashboard and the MTConnect
agent) so a busy MES does not cost a database round trip per request."""

from __future__ import annotations

import logging
from typing import Annotated

from fastapi import Depends, Request, Security
from fastapi.concurrency import run_in_threadpool
from fastapi.security import APIKeyHeader

from api.rest.errors import AuthError, ForbiddenError, TooManyRequestsError
from api.service.keys import KeyCache  # noqa: F401 - the API's key cache, one per app
from api.service.throttle import failed_authentication
from storage.db import KeyRecord

log = logging.getLogger("mebm.api")
ROLE_RANK = {"read": 0, "operate": 1, "admin": 2}
api_key_header = APIKeyHeader(name="X-API-Key", auto_error=False,
                              description="An access key (`mebm keys create --role read|operate|admin`).")


async def current_key(request: Request, header_key: Annotated[str | None, Security(api_key_header)]) -> KeyRecord:
    """The caller's key. Async with a cache fast path: a busy MES costs no thread hop
    and no database round trip per request; a miss looks the key up in a worker thread.

    The key is looked up first: a valid key is always admitted. Failed authentication is
    logged (client address, peer and claimed X-Forwarded-For, method, path; never the
    key) and throttled (:class:`api.service.throttle.AuthThrottle`): past the burst, 429 with
    Retry-After instead of 401."""
    secret = header_key
    if not secret:
        auth = request.headers.get("authorization", "")
        if auth.lower().startswith("bearer "):
            secret = auth[7:].strip()
    state = request.app.state
    if not secret:
        _failed(request, secret, "no key")
        raise AuthError("an access key is required: send it in the X-API-Key header")
    found, rec = state.key_cache.cached(secret)
    if not found:
        rec = await run_in_threadpool(state.key_cache.lookup, state.service.factory, secret)
    if rec is None:
        _failed(request, secret, "unknown or revoked key")
        raise AuthError("unknown or revoked access key")
    return rec


def _failed(request: Request, secret: str | None, why: str) -> None:
    wait_s = failed_authentication(request, secret, why, log)
    if wait_s > 0:
        client = request.client.host if request.client else "unknown"
        raise TooManyRequestsError(f"too many failed authentications from {client}; retry later", wait_s)


def require(role: str):
    """A dependency that admits keys of ``role`` or higher."""

    async def check(key: Annotated[KeyRecord, Depends(current_key)]) -> KeyRecord:
        if ROLE_RANK[key.role] < ROLE_RANK[role]:
            raise ForbiddenError(f"key {key.name!r} has role {key.role!r}; this needs {role!r}")
        return key

    check.__name__ = f"require_{role}"
    return check


ReadKey = Annotated[KeyRecord, Depends(require("read"))]
OperateKey = Annotated[KeyRecord, Depends(require("operate"))]
AdminKey = Annotated[KeyRecord, Depends(require("admin"))]
