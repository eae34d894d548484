"""The agent's HTTP requests under ``/mtconnect`` (MTConnect Part 1, REST protocol):
``probe``, ``current``, ``sample?from=&count=``, each for all devices or one
(``/mtconnect/<device name or uuid>/current``), and ``assets`` (always empty: mebm
keeps no tool, part or program assets). XML unless the request's ``Accept``
asks for ``application/json``. Errors are MTConnectError documents (OUT_OF_RANGE,
INVALID_REQUEST, NO_DEVICE, INVALID_URI, UNSUPPORTED, UNAUTHORIZED), as an agent sends them.

Read-only: only GET. With ``require_key`` any valid API key (``X-API-Key`` or
``Authorization: Bearer``) may read; without it, everyone on the network can. Keys are
checked through the process' one key cache (:mod:`api.service.keys`): revoked is refused
here as on the REST API. Failed keys
are logged and throttled per client address as the REST API's are (an UNAUTHORIZED
document with status 429 and ``Retry-After`` past the burst).
"""

from __future__ import annotations

import logging
import re
from importlib import resources

from fastapi import APIRouter, Request
from fastapi.responses import Response

from api.mtconnect import documents as doc
from api.mtconnect.agent import MTConnectAgent
from api.mtconnect.buffer import OutOfRangeError
from api.service.keys import KeyCache
from api.service.throttle import failed_authentication
from storage.db import StorageError

log = logging.getLogger(__name__)

PREFIX = "/mtconnect"
DEFAULT_COUNT = 100
UNSUPPORTED = ("interval", "at", "to", "path", "heartbeat")  # streaming, history and XPath filters: not served
XML = "application/xml"
JSON = "application/json"
STATUS = {"OUT_OF_RANGE": 400, "INVALID_REQUEST": 400, "UNSUPPORTED": 400, "NO_DEVICE": 404, "INVALID_URI": 404,
          "ASSET_NOT_FOUND": 404, "UNAUTHORIZED": 401, "INTERNAL_ERROR": 503}  # fmt: skip


class MTConnectError(Exception):
    def __init__(self, code: str, message: str):
        super().__init__(message)
        self.code = code


def _wants_json(request: Request) -> bool:
    accept = request.headers.get("accept", "").lower()
    return JSON in accept and "xml" not in accept.split(JSON)[0]


def _secret(request: Request) -> str | None:
    key = request.headers.get("x-api-key")
    if key:
        return key
    auth = request.headers.get("authorization", "")
    return auth[7:].strip() or None if auth.lower().startswith("bearer ") else None


def _int(request: Request, name: str, default: int | None) -> int | None:
    raw = request.query_params.get(name)
    if raw is None:
        return default
    if not re.fullmatch(r"-?[0-9]{1,19}", raw):  # int() would take " 5", "+5" and "1_000"
        raise MTConnectError("INVALID_REQUEST", f"'{name}' must be an integer, not {raw!r}")
    return int(raw)


def make_router(agent: MTConnectAgent) -> APIRouter:
    router = APIRouter(prefix=PREFIX, include_in_schema=False)
    own_keys = KeyCache()  # (an agent mounted without the REST API's app state)

    def respond(request: Request, build) -> Response:
        as_json = _wants_json(request)
        headers = {}
        try:
            if agent.settings.require_key:
                # the key is looked up first (a valid key is always admitted); failures are
                # throttled with the REST API's budget (app.state.auth_throttle, [limits]
                # auth_*failure*): the same address guessing keys on either path is one budget
                secret = _secret(request)
                # the process' one key cache (app.state.key_cache): a key revoked through the API
                # or the dashboard is refused here too as soon as the revocation answered
                keys = getattr(request.app.state, "key_cache", None) or own_keys
                if not secret or keys.lookup(agent.service.factory, secret) is None:
                    wait_s = failed_authentication(request, secret, "MTConnect", log)
                    if wait_s > 0:
                        client = request.client.host if request.client else "unknown"
                        headers["Retry-After"] = str(max(1, round(wait_s)))
                        raise MTConnectError("TOO_MANY_FAILURES", f"too many failed authentications from "
                                             f"{client}; retry in {wait_s:.0f} s")
                    raise MTConnectError("UNAUTHORIZED", "a valid access key is required (X-API-Key header)")
            for name in UNSUPPORTED:
                if name in request.query_params:
                    raise MTConnectError("UNSUPPORTED", f"the parameter '{name}' is not supported by this agent")
            body = build(as_json)
            return Response(body, media_type=JSON if as_json else XML)
        except MTConnectError as exc:
            status, code, msg = STATUS.get(exc.code, 400), exc.code, str(exc)
            if code == "TOO_MANY_FAILURES":  # MTConnect has no code of its own for it
                status, code = 429, "UNAUTHORIZED"
        except OutOfRangeError as exc:
            status, code, msg = 400, "OUT_OF_RANGE", str(exc)
        except StorageError as exc:
            status, code, msg = 503, "INTERNAL_ERROR", f"the database is unavailable: {exc}"
        h = agent.header()
        body = doc.error_json(h, code, msg) if as_json else doc.error_xml(h, code, msg)
        return Response(body, status_code=status, media_type=JSON if as_json else XML, headers=headers)

    def devices(device: str | None):
        devs = agent.devices(device)
        if devs is None:
            raise MTConnectError("NO_DEVICE", f"no device named {device!r}")
        return devs

    def probe(request: Request, device: str | None) -> Response:
        def build(as_json):
            devs = devices(device)
            return (doc.devices_json if as_json else doc.devices_xml)(agent.header(), devs)

        return respond(request, build)

    def current(request: Request, device: str | None) -> Response:
        def build(as_json):
            devs = devices(device)
            return (doc.streams_json if as_json else doc.streams_xml)(agent.header(), devs, agent.current(devs))

        return respond(request, build)

    def sample(request: Request, device: str | None) -> Response:
        def build(as_json):
            devs = devices(device)
            start = _int(request, "from", None)
            count = _int(request, "count", min(DEFAULT_COUNT, agent.buffer.size))
            if start is not None and start < 0:
                raise MTConnectError("OUT_OF_RANGE", f"'from' (={start}) must be a positive sequence number")
            if not 1 <= count <= agent.buffer.size:
                raise MTConnectError("OUT_OF_RANGE", f"'count' (={count}) must be 1..{agent.buffer.size}")
            w = agent.only(agent.buffer.sample(start, count), devs)
            return (doc.streams_json if as_json else doc.streams_xml)(agent.header(), devs, w)

        return respond(request, build)

    @router.get("")
    @router.get("/")
    @router.get("/probe")
    def probe_all(request: Request) -> Response:
        return probe(request, None)

    @router.get("/current")
    def current_all(request: Request) -> Response:
        return current(request, None)

    @router.get("/sample")
    def sample_all(request: Request) -> Response:
        return sample(request, None)

    @router.get("/assets")
    @router.get("/{device}/assets")
    def assets(request: Request, device: str | None = None) -> Response:
        def build(as_json):
            if device is not None:
                devices(device)
            return (doc.assets_json if as_json else doc.assets_xml)(agent.header())

        return respond(request, build)

    @router.get("/asset/{asset_id}")
    @router.get("/assets/{asset_id}")
    def asset(request: Request, asset_id: str) -> Response:
        def build(as_json):
            raise MTConnectError("ASSET_NOT_FOUND", f"no asset {asset_id!r}: mebm keeps no assets")

        return respond(request, build)

    @router.get("/schemas/mebm_streams_2.4.xsd")
    def extension_schema() -> Response:
        return Response(resources.files("api.mtconnect").joinpath(doc.X_XSD).read_bytes(), media_type=XML)

    @router.get("/{device}/probe")
    def probe_one(request: Request, device: str) -> Response:
        return probe(request, device)

    @router.get("/{device}/current")
    def current_one(request: Request, device: str) -> Response:
        return current(request, device)

    @router.get("/{device}/sample")
    def sample_one(request: Request, device: str) -> Response:
        return sample(request, device)

    @router.get("/{device}")
    def probe_named(request: Request, device: str) -> Response:
        return probe(request, device)

    @router.get("/{rest:path}")
    def unknown(request: Request, rest: str) -> Response:
        def build(as_json):
            raise MTConnectError("INVALID_URI", f"{PREFIX}/{rest} is not a request of this agent "
                                 "(probe, current, sample, or <device>/probe|current|sample)")

        return respond(request, build)

    return router
