"""Standard security headers on every response (pure ASGI middleware, so the status
fast path's answers get them too), and ``Cache-Control: no-store`` on the responses
that can carry a secret (``/api/v1/keys``: a created key is shown once)."""

from __future__ import annotations

_COMMON = (
    (b"x-content-type-options", b"nosniff"),
    (b"x-frame-options", b"DENY"),
    (b"referrer-policy", b"no-referrer"),
    (b"cross-origin-opener-policy", b"same-origin"),
    (b"cross-origin-resource-policy", b"same-origin"),
)
_CSP_API = b"default-src 'none'; frame-ancestors 'none'"
# Swagger UI (served from the package, see docs.py) runs one inline script that loads it
_CSP_DOCS = (b"default-src 'self'; img-src 'self' data:; style-src 'self' 'unsafe-inline'; "
             b"script-src 'self' 'unsafe-inline'; frame-ancestors 'none'")
# The dashboard (api/ui): its own scripts, styles and images only; no inline script or style
# (the bars' widths are set by ui.js from data attributes), forms post back to it only
_CSP_UI = (b"default-src 'none'; img-src 'self'; style-src 'self'; script-src 'self'; connect-src 'self'; "
           b"form-action 'self'; base-uri 'none'; frame-ancestors 'none'")
SECRET_PATHS = ("/api/v1/keys", "/ui/sign-in")


class SecurityHeaders:
    def __init__(self, app):
        self.app = app

    async def __call__(self, scope, receive, send):
        if scope["type"] != "http":
            return await self.app(scope, receive, send)
        path = scope["path"]
        csp = _CSP_DOCS if path.startswith("/docs") else _CSP_UI if path.startswith("/ui") else _CSP_API
        extra = [*_COMMON, (b"content-security-policy", csp)]
        if path.startswith(SECRET_PATHS):
            extra += [(b"cache-control", b"no-store"), (b"pragma", b"no-cache")]
        names = {n for n, _ in extra}

        async def with_headers(message):
            if message["type"] == "http.response.start":
                headers = [(n, v) for n, v in message.get("headers", []) if n.lower() not in names]
                message = {**message, "headers": headers + extra}
            await send(message)

        await self.app(scope, receive, with_headers)
