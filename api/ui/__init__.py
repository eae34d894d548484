"""The dashboard: server-rendered pages under ``/ui/`` in the API's process.

Jinja2 templates; the figures are the service's matplotlib PNGs (api/service/figures/axis.py),
so nothing is fetched from a CDN and no build chain is needed. Data comes through the
same service functions as the REST routers; this package never imports ``api.rest``
(an import-linter contract). Sign-in: api/ui/sessions.py. Docs: docs/dashboard.md.
"""

from __future__ import annotations

import inspect
import json
from http import HTTPStatus

from fastapi import FastAPI, Request
from fastapi.exceptions import WebSocketRequestValidationError
from fastapi.responses import FileResponse, RedirectResponse
from fastapi.staticfiles import StaticFiles

from api.ui.circles import router as circles_router
from api.ui.config_routes import router as config_router
from api.ui.maintenance import router as maintenance_router
from api.ui.routes import HERE, SignInRequired, UiForbidden, page, router
from api.ui.sessions import UiState
from storage.db import NotFoundError

__all__ = ["install", "UiState"]


def _as_page(handler):
    """``handler`` (the API's answer to an error, JSON) answering an HTML page under /ui/."""

    async def answer(request: Request, exc: Exception):
        resp = handler(request, exc)
        if inspect.isawaitable(resp):
            resp = await resp
        if not request.url.path.startswith("/ui/") or resp.media_type != "application/json":
            return resp
        try:
            detail = json.loads(resp.body).get("detail")
        except (ValueError, AttributeError):
            detail = None
        if not isinstance(detail, str):
            detail = "; ".join(f"{'.'.join(map(str, e.get('loc', ())))}: {e.get('msg', '')}" for e in detail) \
                if isinstance(detail, list) else HTTPStatus(resp.status_code).phrase
        out = page(request, "error.html", resp.status_code, who=None, title=HTTPStatus(resp.status_code).phrase,
                   message=detail)
        if "retry-after" in resp.headers:
            out.headers["Retry-After"] = resp.headers["retry-after"]
        return out

    return answer


def install(app: FastAPI, state: UiState | None = None) -> UiState:
    """Mount the dashboard on ``app`` (``/ui/``, ``/`` redirecting to it); returns its state
    (``state.sessions.issue_link(key)`` makes a one-time sign-in link)."""
    app.state.ui = state or UiState()
    app.state.ui.sessions.service = app.state.service  # sessions live in the service's database
    app.include_router(router)
    app.include_router(config_router)
    app.include_router(maintenance_router)  # and the axis page's work-order panel
    app.include_router(circles_router)  # and the axis page's circular tests panel
    app.mount("/ui/static", StaticFiles(directory=str(HERE / "static")), name="ui-static")

    @app.get("/", include_in_schema=False)
    def root():
        return RedirectResponse("/ui/", status_code=307)

    @app.get("/favicon.ico", include_in_schema=False)
    def favicon():
        # what a browser asks for on a page without a <link rel="icon"> (the API's JSON, MTConnect's XML)
        return FileResponse(HERE / "static" / "favicon.ico", media_type="image/x-icon",
                            headers={"Cache-Control": "public, max-age=86400"})

    @app.exception_handler(SignInRequired)
    async def sign_in_required(request: Request, exc: SignInRequired):
        if request.url.path.endswith(".frag") or request.method != "GET":
            return page(request, "error.html", 401, who=None, title="Signed out",
                        message="your session has ended: sign in again")
        return RedirectResponse("/ui/sign-in", status_code=303)

    @app.exception_handler(UiForbidden)
    async def forbidden(request: Request, exc: UiForbidden):
        return page(request, "error.html", 403, who=None, title="Refused", message=exc.message)

    # every other error answer of the API (a 422 for an id out of range, a 429 for a measurement
    # already waiting, a 503): an HTML page under /ui, with the same status and Retry-After
    for kind, handler in list(app.exception_handlers.items()):
        if isinstance(kind, type) and kind not in (NotFoundError, SignInRequired, UiForbidden,
                                                   WebSocketRequestValidationError):
            app.add_exception_handler(kind, _as_page(handler))

    # an unknown axis, alert or key: an HTML page under /ui, the API's own answer elsewhere
    api_not_found = app.exception_handlers.get(NotFoundError)

    @app.exception_handler(NotFoundError)
    async def not_found(request: Request, exc: NotFoundError):
        if request.url.path.startswith("/ui/") or api_not_found is None:
            return page(request, "error.html", 404, who=None, title="Not found", message=str(exc))
        return await api_not_found(request, exc)

    return app.state.ui
