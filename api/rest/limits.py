"""Bounds on what a client can make the service do.

- :class:`BodyLimit` (pure ASGI middleware, outermost): a request body larger than
  ``max_body_bytes`` is answered 413 before it is read: at once when ``Content-Length``
  says so, after at most ``max_body_bytes`` when the body is chunked. Key or no key.
- :class:`TokenBucket`: ``per_minute`` tokens per key, at most ``burst`` saved up; used
  for manual triggers per key and for failed authentication per client address.
  Bounded memory: at most ``max_keys`` buckets (the least recently used go first).
"""

from __future__ import annotations

import json
import threading
import time
from collections import OrderedDict

from starlette.exceptions import HTTPException


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


class TokenBucket:
    """``take(key)`` -> 0 when allowed (a token is used), else seconds until one is free.
    ``blocked(key)`` tells the same without using a token. Thread-safe."""

    def __init__(self, per_minute: float, burst: int, *, max_keys: int = 10000, clock=time.monotonic):
        self.rate_per_s = per_minute / 60.0
        self.burst = max(int(burst), 1)
        self.max_keys = max_keys
        self.clock = clock
        self._buckets: OrderedDict[str, tuple[float, float]] = OrderedDict()  # key -> (tokens, at)
        self._lock = threading.Lock()

    def _level(self, key: str, now: float) -> float:
        tokens, at = self._buckets.get(key, (float(self.burst), now))
        return min(float(self.burst), tokens + (now - at) * self.rate_per_s)

    def _wait_s(self, tokens: float) -> float:
        return (1.0 - tokens) / self.rate_per_s if self.rate_per_s > 0 else 3600.0

    def blocked(self, key: str) -> float:
        with self._lock:
            tokens = self._level(key, self.clock())
            return 0.0 if tokens >= 1.0 else self._wait_s(tokens)

    def take(self, key: str) -> float:
        with self._lock:
            now = self.clock()
            tokens = self._level(key, now)
            if tokens < 1.0:
                self._buckets[key] = (tokens, now)
                self._buckets.move_to_end(key)
                return self._wait_s(tokens)
            self._buckets[key] = (tokens - 1.0, now)
            self._buckets.move_to_end(key)
            while len(self._buckets) > self.max_keys:
                self._buckets.popitem(last=False)
            return 0.0
