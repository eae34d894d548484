"""/machines: list machines and their axes; admins add machines and axes."""

from __future__ import annotations

from fastapi import APIRouter, status

from api.rest import convert, schemas as sc
from api.rest.auth import AdminKey, ReadKey
from api.rest.deps import MachineId, ServiceDep, SessionDep
from api.service.config.input import axis_settings
from storage.db import config_repo

router = APIRouter(tags=["machines"])


@router.get("/machines", response_model=list[sc.MachineOut], summary="All machines")
def list_machines(s: SessionDep, _k: ReadKey):
    return [convert.machine(m) for m in config_repo.list_machines(s)]


@router.post("/machines", response_model=sc.MachineOut, status_code=status.HTTP_201_CREATED,
             summary="Add a machine (admin)")
def create_machine(body: sc.MachineIn, s: SessionDep, _k: AdminKey):
    return convert.machine(config_repo.create_machine(s, body.name, body.description))


@router.get("/machines/{machine_id}/axes", response_model=list[sc.AxisOut], summary="The axes of a machine")
def list_axes(machine_id: MachineId, s: SessionDep, svc: ServiceDep, _k: ReadKey):
    return [convert.axis(a, svc.scheduler.next_run(a.id)) for a in config_repo.list_axes(s, machine_id)]


@router.post("/machines/{machine_id}/axes", response_model=sc.AxisOut, status_code=status.HTTP_201_CREATED,
             summary="Add a monitored axis to a machine (admin)")
def create_axis(machine_id: MachineId, body: sc.AxisIn, s: SessionDep, svc: ServiceDep, _k: AdminKey):
    st = axis_settings(body, allow_link_local=svc.settings.limits.allow_link_local_controllers,
                       profiles_dir=svc.settings.profiles_path)
    a = config_repo.create_axis(s, machine_id, st)
    s.commit()
    svc.axis_changed(a)
    return convert.axis(a, svc.scheduler.next_run(a.id))
