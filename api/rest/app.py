"""The FastAPI application factory.

``create_app(settings)`` builds the app; on start-up (lifespan) it starts the
:class:`api.service.service.Service` (migrations, configured axes, keys, simulated
controller, scheduler) unless a started service is handed in (tests).
"""

from __future__ import annotations

import contextlib
import logging
import re

from fastapi import FastAPI

from api.rest import errors
from api.rest.auth import KeyCache
from api.rest.docs import install_docs
from api.rest.headers import SecurityHeaders
from api.rest.limits import AuthThrottle, BodyLimit, TokenBucket
from api.rest.metrics import make_registry
from api.rest.proxies import ForwardedFor
from api.rest.routers import (alerts, axes, circles, compensation, gap, health, interfaces, keys, machines,
                              maintenance, measurements, plots)
from api.rest.routers import workers
from api.rest.schemas import ERROR_RESPONSES
from api.rest.status_body import StatusFastPath, status_json
from api.service.config.settings import Settings
from api.service.cycles.runner import CycleRunner
from api.service.service import Service
from api.service.throttle import log_refusals
from api.ui import install as install_ui

API_PREFIX = "/api/v1"
# Routers under /api/v1, included explicitly: a renamed module is an ImportError, never a
# silently missing endpoint.
ROUTERS = (machines, axes, measurements, alerts, plots, keys, gap, compensation, interfaces, maintenance, workers,
           circles)
log = logging.getLogger("mebm.api")
CIRCLE_POST = re.compile(API_PREFIX + r"/machines/[^/]+/circles(?:/import)?")  # a circular test's samples

DESCRIPTION = """
Manufacturing-error-based maintenance (MEBM) of machine-tool feed drives.

The service measures each monitored axis on a schedule (a round trip read through the
motor and table encoders), estimates the transient backlash error (TBE) of every
configured machining task, and raises an alert when a TBE passes its permissible error,
telling the maintenance team the backlash to restore.

**Access**: every endpoint except `/healthz` needs a key in the `X-API-Key` header
(or `Authorization: Bearer`). Roles: `read` (an MES), `operate` (trigger cycles,
acknowledge alerts), `admin` (configure machines, axes, tasks, schedules, keys).

**Errors**: 422 names the offending field, 404 unknown id, 401/403 keys,
409 conflicts, 503 database unavailable.
"""


def _start_interfaces(app: FastAPI, svc: Service, settings: Settings) -> list:
    """The event consumers the configuration turns on: MQTT, webhooks."""
    app.state.mqtt = app.state.webhooks = None
    started = []
    if settings.mqtt.url:
        from api.mqtt import MqttPublisher

        app.state.mqtt = MqttPublisher(svc, settings.mqtt)
        started.append(app.state.mqtt)
    if settings.webhooks.urls:
        from api.webhooks import WebhookSender

        app.state.webhooks = WebhookSender(svc, settings.webhooks)
        started.append(app.state.webhooks)
    return started


def _start_opcua(app: FastAPI, svc: Service, settings: Settings, given) -> list:
    """The OPC UA server: the one handed in (``mebm serve`` starts it before its banner),
    else one of our own when ``[opcua] enabled``. Started after the service (it seeds from
    the database); one that cannot listen is logged and left off, never fatal."""
    app.state.opcua = given
    if given is not None or not settings.opcua.enabled:
        return []
    from api.opcua import OpcuaServer

    app.state.opcua = OpcuaServer(svc, settings.opcua)
    app.state.opcua.start()
    return [app.state.opcua]


def create_app(settings: Settings, *, service: Service | None = None, runner: CycleRunner | None = None,
               opcua=None) -> FastAPI:  # fmt: skip
    owned = service is None
    svc = service or Service(settings, runner=runner)

    @contextlib.asynccontextmanager
    async def lifespan(app: FastAPI):
        svc.render_status = lambda axis_id: status_json(app.state, svc, axis_id, svc.status.get(axis_id))
        started = _start_interfaces(app, svc, settings)  # subscribed before the first cycle can be saved
        agent = app.state.mtconnect
        if agent is not None:
            agent.start()
            started.append(agent)
        try:
            if owned:
                svc.start()
            started += _start_opcua(app, svc, settings, opcua)
            if agent is not None:
                agent.seed()  # /current is right from the first request after a restart
            for machine, _ in settings.machines:
                if app.state.mqtt is not None:
                    app.state.mqtt.link(machine)  # the birth message, before any measurement
            yield
        finally:
            log_refusals(app.state.auth_throttle.flush(), log)  # the refusals counted since the last line
            for x in started:
                x.close()
            if owned:
                svc.stop()

    app = FastAPI(title="mebm", version="0.1.0", description=DESCRIPTION, lifespan=lifespan,
                  openapi_url=f"{API_PREFIX}/openapi.json", docs_url=None, redoc_url=None)
    install_docs(app, f"{API_PREFIX}/openapi.json")  # Swagger UI from the package, no CDN
    app.state.service = svc
    app.state.mqtt = app.state.webhooks = None
    app.state.opcua = opcua
    app.state.key_cache = KeyCache()
    app.state.status_json = {}  # axis id -> (status object, its encoded JSON): see status_body.py
    app.state.metrics = make_registry(svc)
    errors.install(app)
    app.add_middleware(StatusFastPath, state=app.state)
    lim = settings.limits
    app.state.trigger_limit = TokenBucket(lim.triggers_per_minute, lim.trigger_burst)
    app.state.auth_throttle = AuthThrottle(lim.auth_failures_per_minute, lim.auth_failure_burst,
                                           lim.auth_address_failures_per_minute, lim.auth_address_failure_burst)
    app.add_middleware(BodyLimit, max_bytes=lim.max_body_bytes,  # before anything reads the body
                       larger=(("POST", CIRCLE_POST, lim.max_circle_body_bytes, "limits.max_circle_body_bytes"),))
    app.add_middleware(SecurityHeaders)
    app.add_middleware(ForwardedFor, trusted=settings.trusted_proxies)  # outermost: all see the client
    # each module's router straight into the app, with the API's prefix and error answers:
    # FastAPI copies a route at every include, and a router in between doubled the work of
    # each app's start (the OpenAPI document is the same)
    for module in ROUTERS:
        app.include_router(module.router, prefix=API_PREFIX, responses=ERROR_RESPONSES)
    app.include_router(health.router, responses={k: v for k, v in ERROR_RESPONSES.items() if k in (401, 403, 503)})
    install_ui(app)  # the dashboard under /ui/; app.state.ui issues sign-in links
    app.state.mtconnect = None
    if settings.mtconnect.enabled:  # an MTConnect agent on the same port; it imports no REST
        from api.mtconnect import MTConnectAgent, make_router

        app.state.mtconnect = MTConnectAgent(svc, settings.mtconnect)
        app.include_router(make_router(app.state.mtconnect))
    return app
