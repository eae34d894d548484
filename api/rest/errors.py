"""The one place errors become HTTP status codes.

422 bad input (the message names the field), 404 unknown id, 409 conflict,
401/403 keys, 413 body too large, 429 rate limits and a manual measurement already
waiting (with ``Retry-After``), 503 database down or a figure not drawn in time. Anything else is logged and answered 500 without
internals.
"""

from __future__ import annotations

import logging
import math

from fastapi import FastAPI, Request
from fastapi.exceptions import RequestValidationError
from fastapi.responses import JSONResponse

from api.service.figures.process import RenderUnavailable
from core.errors import InputError, MebmError
from storage.db import ConflictError, DatabaseUnavailableError, NotFoundError, StorageError, WaitingCycleError

log = logging.getLogger("mebm.api")


class AuthError(MebmError):
    """401: no key, or a key that is not (or no longer) valid."""

    status_code = 401


class ForbiddenError(MebmError):
    """403: a valid key whose role does not allow the action."""

    status_code = 403


class TooManyRequestsError(MebmError):
    """429: a rate limit; ``retry_after_s`` says when to ask again."""

    status_code = 429

    def __init__(self, message: str, retry_after_s: float):
        super().__init__(message)
        self.retry_after_s = retry_after_s


def too_many(message: str, retry_after_s: float, **extra) -> JSONResponse:
    return JSONResponse({"detail": message, **extra}, status_code=429,
                        headers={"Retry-After": str(max(1, math.ceil(retry_after_s)))})


def _body(status: int, message: str, **extra) -> JSONResponse:
    headers = {"WWW-Authenticate": "ApiKey"} if status == 401 else None
    return JSONResponse({"detail": message, **extra}, status_code=status, headers=headers)


def _field(loc) -> str:
    parts = [str(p) for p in loc if p not in ("body", "query", "path", "header")]
    return ".".join(parts) or ".".join(str(p) for p in loc)


def _json_position(doc, pos: int) -> tuple[int, int]:
    """Line and column (both from 1) of character ``pos`` of a request body, as json counts them."""
    if isinstance(doc, (bytes, bytearray)):
        doc = doc.decode("utf-8", "replace")
    if not isinstance(doc, str):
        return 1, pos + 1
    line = doc.count("\n", 0, pos) + 1
    return line, pos - (doc.rfind("\n", 0, pos) + 1) + 1


def _error_entry(e: dict, body) -> dict:
    """One entry of a 422's ``errors``. A body that is not JSON at all gets the position of
    the fault (line, column and character offset) and json's reason in words, instead of
    pydantic's location ``("body", <offset>)`` and "JSON decode error"."""
    if e.get("type") != "json_invalid":
        return {"field": _field(e.get("loc", ())), "message": e.get("msg", "invalid")}
    loc = e.get("loc", ())
    pos = loc[-1] if loc and isinstance(loc[-1], int) else 0
    line, column = _json_position(body, pos)
    reason = str((e.get("ctx") or {}).get("error", "not JSON")).rstrip()
    where = reason if reason.endswith(" at") else f"{reason} at"  # json's "Unterminated string starting at"
    message = (f"not valid JSON: {where} line {line}, column {column} (character {pos}): "
               "the body is cut short or not JSON; send the whole JSON document")
    return {"field": "body", "message": message, "line": line, "column": column, "position": pos}


def install(app: FastAPI) -> None:
    @app.exception_handler(RequestValidationError)
    async def _validation(_req: Request, exc: RequestValidationError):
        errors = [_error_entry(e, exc.body) for e in exc.errors()]
        msg = "; ".join(f"{e['field']}: {e['message']}" for e in errors) or "invalid request"
        return _body(422, msg, errors=errors)

    @app.exception_handler(AuthError)
    async def _auth(_req, exc):
        return _body(401, str(exc))

    @app.exception_handler(ForbiddenError)
    async def _forbidden(_req, exc):
        return _body(403, str(exc))

    @app.exception_handler(TooManyRequestsError)
    async def _too_many(_req, exc):
        return too_many(str(exc), exc.retry_after_s)

    @app.exception_handler(WaitingCycleError)
    async def _waiting(_req, exc):
        return too_many(str(exc), exc.retry_after_s, waiting_measurement_id=getattr(exc.cycle, "id", None))

    @app.exception_handler(NotFoundError)
    async def _not_found(_req, exc):
        return _body(404, str(exc))

    @app.exception_handler(ConflictError)
    async def _conflict(_req, exc):
        return _body(409, str(exc))

    @app.exception_handler(DatabaseUnavailableError)
    async def _db_down(_req, exc):
        return _body(503, f"database unavailable, retry later: {exc}")

    @app.exception_handler(RenderUnavailable)
    async def _render(_req, exc):
        log.error("figure not drawn: %s", exc)
        return _body(503, f"the figure could not be drawn now, retry later: {exc}")

    @app.exception_handler(InputError)
    async def _input(_req, exc):
        return _body(422, str(exc))

    @app.exception_handler(StorageError)
    async def _storage(_req, exc):
        log.error("storage error: %s", exc)
        return _body(500, "internal storage error")

    @app.exception_handler(MebmError)
    async def _mebm(_req, exc):
        log.error("unexpected error: %s", exc)
        return _body(500, f"{type(exc).__name__}: {exc}")
