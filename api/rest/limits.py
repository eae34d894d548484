"""Bounds on what a client can make the service do.

- :class:`BodyLimit` (pure ASGI middleware, outermost): a request body larger than
  ``max_body_bytes`` is answered 413 before it is read: at once when ``Content-Length``
  says so, after at most ``max_body_bytes`` when the body is chunked. Key or no key.
- :class:`TokenBucket` (api.service.throttle): manual triggers per key.
- :class:`AuthThrottle` (api.service.throttle): failed authentications, on every path
  that takes a key (REST, dashboard sign-in, MTConnect).
"""

from __future__ import annotations

import json
import re

from starlette.exceptions import HTTPException

from api.service.throttle import AuthThrottle, TokenBucket  # noqa: F401 - the API's limits in one place


class BodyTooLarge(HTTPException):
    def __init__(self, max_bytes: int, setting: str = "limits.max_body_bytes"):
        super().__init__(status_code=413, detail=f"request body larger than {max_bytes} bytes ({setting})")


def _json_response(status: int, detail: str, extra_headers=()) -> tuple[dict, dict]:
    body = json.dumps({"detail": detail}).encode()
    start = {"type": "http.response.start", "status": status, "headers": [
        (b"content-type", b"application/json"), (b"content-length", str(len(body)).encode()),
        (b"connection", b"close"), *extra_headers]}
    return start, {"type": "http.response.body", "body": body}


class BodyLimit:
    """``larger``: (method, path pattern, max_bytes, setting) of the routes whose bodies are
    data sets rather than requests (a circular test's samples), with a limit of their own."""

    def __init__(self, app, max_bytes: int, larger: tuple[tuple[str, re.Pattern, int, str], ...] = ()):
        self.app = app
        self.max_bytes = max_bytes
        self.larger = larger

    async def __call__(self, scope, receive, send):
        if scope["type"] != "http":
            return await self.app(scope, receive, send)
        max_bytes, setting = self.max_bytes, "limits.max_body_bytes"
        for method, pattern, n, name in self.larger:
            if scope["method"] == method and pattern.fullmatch(scope["path"]):
                max_bytes, setting = n, name
                break
        length = None
        for name, value in scope["headers"]:
            if name == b"content-length":
                try:
                    length = int(value)
                except ValueError:
                    length = None
                break
        if length is not None and length > max_bytes:
            start, body = _json_response(413, BodyTooLarge(max_bytes, setting).detail)
            await send(start)
            await send(body)
            return
        received = 0
        started = False

        async def limited_receive():
            nonlocal received
            message = await receive()
            if message["type"] == "http.request":
                received += len(message.get("body", b""))
                if received > max_bytes:
                    raise BodyTooLarge(max_bytes, setting)  # FastAPI answers an HTTPException itself
            return message

        async def tracking_send(message):
            nonlocal started
            if message["type"] == "http.response.start":
                started = True
            await send(message)

        try:
            await self.app(scope, limited_receive, tracking_send)
        except BodyTooLarge as exc:  # read outside a route (no handler on the way)
            if started:
                raise
            start, body = _json_response(413, exc.detail)
            await send(start)
            await send(body)
