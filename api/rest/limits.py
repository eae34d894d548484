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

from starlette.exceptions import HTTPException

from api.service.throttle import AuthThrottle, TokenBucket  # noqa: F401 - the API's limits in one place


class BodyTooLarge(HTTPException):
    def __init__(self, max_bytes: int):
        super().__init__(status_code=413, detail=f"request body larger than {max_bytes} bytes (limits.max_body_bytes)")


def _json_response(status: int, detail: str, extra_headers=()) -> tuple[dict, dict]:
    body = json.dumps({"detail": detail}).encode()
    start = {"type": "http.response.start", "status": status, "headers": [
        (b"content-type", b"application/json"), (b"content-length", str(len(body)).encode()),
        (b"connection", b"close"), *extra_headers]}
    return start, {"type": "http.response.body", "body": body}


class BodyLimit:
    def __init__(self, app, max_bytes: int):
        self.app = app
        self.max_bytes = max_bytes

    async def __call__(self, scope, receive, send):
        if scope["type"] != "http":
            return await self.app(scope, receive, send)
        length = None
        for name, value in scope["headers"]:
            if name == b"content-length":
                try:
                    length = int(value)
                except ValueError:
                    length = None
                break
        if length is not None and length > self.max_bytes:
            start, body = _json_response(413, BodyTooLarge(self.max_bytes).detail)
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
                if received > self.max_bytes:
                    raise BodyTooLarge(self.max_bytes)  # FastAPI answers an HTTPException itself
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
