"""/healthz (no key: for load balancers and container health checks) and /metrics."""

from __future__ import annotations

import asyncio
import time

import anyio
import anyio.to_thread
from fastapi import APIRouter, Request, Response
from fastapi.responses import JSONResponse
from prometheus_client import CONTENT_TYPE_LATEST

from api.rest import metrics, schemas as sc
from api.rest.auth import ReadKey
from api.rest.deps import ServiceDep

router = APIRouter(tags=["health"])
VERSION = "0.1.0"


@router.get("/healthz", response_model=sc.Health, responses={503: {"model": sc.Health}},
            summary="Can the service store what it measures: database writable, data folder writable, "
                    "free disk above the floor (no key needed); 503 when degraded, with the reasons")
async def healthz(request: Request, svc: ServiceDep):
    # the last report, answered on the event loop (its checks run again on a thread of
    # their own, api.service.health); when it must be computed first, on threads of its
    # own: however many requests hold the shared worker threads (figures, slow clients), a
    # load balancer's health check does not queue behind them
    rep = svc.health.report(block=False)
    if rep is not None:
        return _healthz(request, svc, rep)
    return await anyio.to_thread.run_sync(_healthz, request, svc, limiter=_health_limiter())


_LIMITERS: dict = {}


def _health_limiter() -> anyio.CapacityLimiter:
    """Two threads for /healthz, per event loop (a test client runs a loop of its own)."""
    loop = asyncio.get_running_loop()
    lim = _LIMITERS.get(id(loop))
    if lim is None or lim[0] is not loop:
        lim = _LIMITERS[id(loop)] = (loop, anyio.CapacityLimiter(2))
        for k in [k for k, (lp, _) in _LIMITERS.items() if lp.is_closed()]:
            del _LIMITERS[k]
    return lim[1]


def _healthz(request: Request, svc, rep=None) -> JSONResponse:
    rep = rep or svc.health.report()
    ua = request.app.state.opcua
    opcua = None if ua is None else (f"listening on {ua.endpoint}" if ua.running else f"off: {ua.error or 'stopped'}")
    body = sc.Health(status=rep.status, database=rep.database,
                     data_dir="ok" if rep.data_dir_writable else "not writable",
                     free_disk_mb=None if rep.free_disk_bytes is None else round(rep.free_disk_bytes / 1e6, 1),
                     problems=list(rep.problems), version=VERSION, uptime_s=time.time() - svc.started_at,
                     spooled_cycles=svc.spooled_count(), opcua=opcua)
    return JSONResponse(body.model_dump(), status_code=200 if rep.ok else 503)


@router.get("/metrics", response_class=Response,
            responses={200: {"content": {"text/plain": {}}, "description": "Prometheus text format"}},
            summary="Prometheus metrics (read key; Prometheus sends it as a bearer token)")
def prometheus(request: Request, _k: ReadKey):
    return Response(metrics.render(request.app.state.metrics), media_type=CONTENT_TYPE_LATEST)
