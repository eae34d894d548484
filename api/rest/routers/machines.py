"""/machines: list machines and their axes; admins add machines and axes."""

from __future__ import annotations

from fastapi import APIRouter, status

from api.rest import convert, schemas as sc
from api.rest.auth import AdminKey, ReadKey
from api.rest.deps import MachineId, ServiceDep, SessionDep
from core.dataset import AxisSpec
from core.errors import InputError, MebmError
from core.tbe import MachiningTask
from storage.db import AxisSettings, Schedule, config_repo

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


def tasks_from(body: list[sc.TaskIn], gain_per_s: float) -> tuple[MachiningTask, ...]:
    tasks = []
    for i, t in enumerate(body):
        try:
            task = MachiningTask(name=t.name, profile=t.profile, feed_mm_min=t.feed_mm_min, gain_per_s=gain_per_s,
                                 tolerance_um=t.tolerance_um, radius_mm=t.radius_mm, angle_deg=t.angle_deg)
            task.backlash_limit_um()  # a tolerance the model cannot map is refused now, not at the next cycle
        except MebmError as exc:
            raise type(exc)(f"tasks[{i}]: {exc}") from exc
        tasks.append(task)
    return tuple(tasks)


@router.post("/machines/{machine_id}/axes", response_model=sc.AxisOut, status_code=status.HTTP_201_CREATED,
             summary="Add a monitored axis to a machine (admin)")
def create_axis(machine_id: MachineId, body: sc.AxisIn, s: SessionDep, svc: ServiceDep, _k: AdminKey):
    problem = sc.link_local_problem(body.controller_url)
    if problem and not svc.settings.limits.allow_link_local_controllers:
        raise InputError(problem)
    try:
        spec = AxisSpec(body.name, body.transmission_mm_per_rev, body.screw_lead_mm, body.position_gain_per_s,
                        tuple(body.travel_mm))
    except MebmError as exc:
        raise type(exc)(str(exc)) from exc
    st = AxisSettings(
        spec=spec, controller_url=body.controller_url, measure_feed_mm_min=body.measure_feed_mm_min,
        measure_acceleration_mm_s2=body.measure_acceleration_mm_s2, warning_fraction=body.warning_fraction,
        decision_rule=body.decision_rule, worst_case_temperature_c=body.worst_case_temperature_c, schedule=Schedule(body.schedule.interval_s, body.schedule.cron, body.schedule.enabled),
        tasks=tasks_from(body.tasks, body.position_gain_per_s),
    )
    if st.schedule.cron is not None:
        from api.service.scheduler import make_trigger

        make_trigger(st.schedule)
    a = config_repo.create_axis(s, machine_id, st)
    s.commit()
    svc.axis_changed(a)
    return convert.axis(a, svc.scheduler.next_run(a.id))
