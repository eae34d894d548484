"""``/docs``: Swagger UI served from the installed package (``swagger-ui-bundle-v2``),
so the page works on a shop network without Internet access (FastAPI's default loads it
from a CDN)."""

from __future__ import annotations

import logging

from fastapi import FastAPI
from fastapi.openapi.docs import get_swagger_ui_html
from fastapi.staticfiles import StaticFiles

log = logging.getLogger("mebm.api")
ASSETS = "/docs/assets"


def install_docs(app: FastAPI, openapi_url: str) -> None:
    try:
        import swagger_ui_bundle
    except ImportError:  # pragma: no cover - a dependency; without it, no /docs rather than a CDN
        log.warning("swagger-ui-bundle-v2 is not installed: /docs is not served")
        return
    app.mount(ASSETS, StaticFiles(directory=swagger_ui_bundle.swagger_ui_path), name="swagger-ui")

    @app.get("/docs", include_in_schema=False)
    async def swagger_ui():
        return get_swagger_ui_html(
            openapi_url=openapi_url, title=f"{app.title} - API docs",
            swagger_js_url=f"{ASSETS}/swagger-ui-bundle.js", swagger_css_url=f"{ASSETS}/swagger-ui.css",
            swagger_favicon_url=f"{ASSETS}/favicon-32x32.png",
        )
