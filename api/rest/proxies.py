"""Which address a request comes from: the TCP peer, or, when that peer is one of the
configured reverse proxies (``[server] trusted_proxies``), the client it names in
``X-Forwarded-For``. From any other peer the header is only a claim: it is logged, never
used.

The app applies uvicorn's own ``ProxyHeadersMiddleware`` (same parsing and trust rules)
itself, and ``mebm serve`` runs uvicorn with ``proxy_headers=False``: uvicorn's wrapping
would replace the peer before the app sees it (a throttled address' log line names
both), and its default trusts 127.0.0.1 and the ``FORWARDED_ALLOW_IPS`` environment.
``Forwarded`` (RFC 7239) is not read."""

from __future__ import annotations

from uvicorn.middleware.proxy_headers import ProxyHeadersMiddleware

from api.service.throttle import PEER


class ForwardedFor:
    def __init__(self, app, trusted: tuple[str, ...] = ()):
        self.app = app
        self.inner = ProxyHeadersMiddleware(app, trusted_hosts=list(trusted)) if trusted else app

    async def __call__(self, scope, receive, send):
        if scope["type"] in ("http", "websocket"):
            scope[PEER] = scope.get("client")
        return await self.inner(scope, receive, send)
