"""The body of ``GET /axes/{id}/status``, the endpoint an MES polls, and its fast path.

The body is validated (``schemas.AxisStatusOut``) and encoded once per computed status;
per request only the age of the measurement and the next scheduled run are appended.
:class:`StatusFastPath` is an ASGI middleware that answers the poll straight from the
caches when the caller's key is already verified (key cache) and the axis' status is
cached: no routing, dependency solving or response validation per request. Anything
else (unknown or unverified key, an axis not cached, a malformed id, any surprise)
goes through the FastAPI route, which gives the same body and every error response.
"""

from __future__ import annotations

import json
import logging
import re

from api.rest import convert
from api.service.status import AxisStatus
from storage.db import utcnow

log = logging.getLogger("mebm.api")

STATUS_PATH = re.compile(r"/api/v1/axes/([1-9][0-9]{0,9})/status")
_MAX_ID = 2**31 - 1


def _dumps(obj) -> str:
    # as Starlette's JSONResponse renders
    return json.dumps(obj, ensure_ascii=False, allow_nan=False, indent=None, separators=(",", ":"))


def cached_status(svc, axis_id: int) -> AxisStatus | None:
    """The cached status without waiting: a fresh one, or a stale one while a background
    thread recomputes it (pollers never queue behind the recomputation); None if the
    axis has none cached (the caller computes it, and an unknown axis is a 404 there)."""
    st = svc.status.fresh(axis_id)
    if st is None:
        st = svc.status.stale(axis_id)
        if st is not None:
            svc.status.refresh_in_background(axis_id)
    return st


def status_json(state, svc, axis_id: int, st: AxisStatus) -> bytes:
    """The JSON body for ``st``: ``state.status_json`` memoises the encoded static part."""
    memos = state.status_json
    memo = memos.get(axis_id)
    if memo is None or memo[0] is not st:
        body = convert.status(st, utcnow(), None).model_dump(mode="json")
        body.pop("age_s", None)
        body.pop("next_run_at", None)
        memo = memos[axis_id] = (st, _dumps(body)[:-1].encode())  # without the closing brace
    latest = st.latest
    age_s = (utcnow() - latest.measured_at).total_seconds() if latest is not None else None
    nxt = svc.scheduler.next_run(axis_id)
    tail = {"age_s": age_s, "next_run_at": nxt.isoformat().replace("+00:00", "Z") if nxt is not None else None}
    return memo[1] + b"," + _dumps(tail)[1:].encode()


def _api_key(headers) -> str | None:
    # the first of repeated headers, as Starlette's Headers.get (the route) takes it
    key = auth = None
    for name, value in headers:
        if name == b"x-api-key" and key is None:
            key = value
        elif name == b"authorization" and auth is None:
            auth = value
    if key:
        return key.decode("latin-1")
    if auth and auth[:7].lower() == b"bearer ":
        return auth[7:].strip().decode("latin-1") or None
    return None


class StatusFastPath:
    """Pure ASGI middleware: see the module docstring. ``app`` is the rest of the stack;
    the FastAPI application's ``state`` (key cache, service, memos) is read per request."""

    def __init__(self, app, state):
        self.app = app
        self.state = state

    async def __call__(self, scope, receive, send):
        if scope["type"] == "http" and scope["method"] == "GET" and not scope.get("query_string"):
            m = STATUS_PATH.fullmatch(scope["path"])
            if m is not None:
                body = self._answer(scope, int(m.group(1)))
                if body is not None:
                    await send({"type": "http.response.start", "status": 200, "headers": [
                        (b"content-length", str(len(body)).encode()), (b"content-type", b"application/json")]})
                    await send({"type": "http.response.body", "body": body})
                    return
        await self.app(scope, receive, send)

    def _answer(self, scope, axis_id: int) -> bytes | None:
        if axis_id > _MAX_ID:
            return None
        try:
            secret = _api_key(scope["headers"])
            if not secret:
                return None
            found, rec = self.state.key_cache.cached(secret)
            if not found or rec is None:
                return None  # every role may read the status; unknown keys get their 401 from the route
            svc = self.state.service
            st = cached_status(svc, axis_id)
            if st is None:
                return None
            return status_json(self.state, svc, axis_id, st)
        except Exception:  # noqa: BLE001 - the regular route answers, with its error handling
            log.debug("status fast path fell back to the route", exc_info=True)
            return None
