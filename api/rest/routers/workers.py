"""/workers: the workers of the fleet, their axes and last heartbeat."""

from __future__ import annotations

from datetime import datetime

from fastapi import APIRouter
from pydantic import BaseModel, Field

from api.rest.auth import ReadKey
from api.rest.deps import ServiceDep
from api.service.cycles.leases import workers_overview

router = APIRouter(tags=["workers"])


class WorkerAxisOut(BaseModel):
    id: int
    machine: str
    name: str


class WorkerOut(BaseModel):
    id: str = Field(description="a uuid per process start")
    name: str
    host: str
    pid: int
    live: bool = Field(description="its heartbeat is younger than its lease time")
    pinned: list[str] | None = Field(description="the machine/axis patterns it may run; null: any axis")
    lease_s: float
    started_at: datetime
    heartbeat_at: datetime
    stopped_at: datetime | None
    takeovers: int = Field(description="axes it took over from a worker whose lease had expired")
    axes: list[WorkerAxisOut] = Field(description="the axes it holds a lease on now")
    this_process: bool = Field(description="the worker that answers this request")


@router.get("/workers", response_model=list[WorkerOut],
            summary="The live workers (and those stopped within the last hour), their axes and last heartbeat")
def list_workers(svc: ServiceDep, _k: ReadKey):
    return [WorkerOut(**w) for w in workers_overview(svc)]
