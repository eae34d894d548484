"""The configuration pages (admin, as the REST API's configuration endpoints): machines,
axes, machining tasks and schedules. Validation: api/ui/config_forms.py (the REST
bodies' models and builders, so both refuse the same values with the same message)."""

from __future__ import annotations

from fastapi import APIRouter, Request
from fastapi.responses import HTMLResponse

from api.service.config.input import axis_settings, machining_tasks, schedule_of
from api.ui import config_forms as cf
from api.ui.routes import Id, Posted, Viewer, Who, back, page
from core.errors import MebmError
from storage.db import ConflictError, config_repo, session_scope

router = APIRouter(prefix="/ui/config", include_in_schema=False)


def _svc(request: Request):
    return request.app.state.service


def _overview(request: Request, who: Viewer, *, msg: str | None = None, machine_form: cf.Checked | None = None,
              status_code: int = 200) -> HTMLResponse:
    svc = _svc(request)
    with session_scope(svc.factory) as s:
        machines = config_repo.list_machines(s)
        axes = config_repo.list_axes(s)
    by_machine = {m.id: [a for a in axes if a.machine_id == m.id] for m in machines}
    return page(request, "config.html", status_code, who=who, msg=msg, machines=machines, axes=by_machine,
                next_run=svc.scheduler.next_run, mf=machine_form or cf.Checked(None, form={"name": "", "description": ""}))


@router.get("", response_class=HTMLResponse)
def config_page(request: Request, who: Who, msg: str | None = None):
    who.require("admin")
    return _overview(request, who, msg=msg)


@router.post("/machines", response_class=HTMLResponse)
async def add_machine(request: Request, who: Posted):
    who.require("admin")
    checked = cf.machine(await request.form())
    if checked.value is None:
        return _overview(request, who, machine_form=checked, status_code=422)
    try:
        with session_scope(_svc(request).factory) as s:
            m = config_repo.create_machine(s, checked.value.name, checked.value.description)
    except ConflictError as exc:
        checked.errors["name"] = str(exc)
        return _overview(request, who, machine_form=checked, status_code=409)
    return back("/ui/config", f"machine {m.name!r} added: add its axes")


# -- a new axis --------------------------------------------------------------------------------
AXIS_DEFAULTS = {"controller_url": "modbus://", "measure_feed_mm_min": "2000", "measure_acceleration_mm_s2": "500",
                 "warning_fraction": "0.9", "decision_rule": "guarded", "worst_case_temperature_c": "30",
                 "interval_s": "86400", "enabled": True}


def _axis_form(request: Request, who: Viewer, machine_id: int, checked: cf.Checked | None = None,
               status_code: int = 200) -> HTMLResponse:
    with session_scope(_svc(request).factory) as s:
        m = next((m for m in config_repo.list_machines(s) if m.id == machine_id), None)
    if m is None:
        from storage.db import NotFoundError

        raise NotFoundError("machine", machine_id)
    form = {f: "" for f in cf.AXIS_FIELDS} | AXIS_DEFAULTS if checked is None else checked.form
    return page(request, "config_axis_new.html", status_code, who=who, machine=m, f=form,
                errors=checked.errors if checked else {})


@router.get("/machines/{machine_id}/axes/new", response_class=HTMLResponse)
def new_axis_page(request: Request, machine_id: Id, who: Who):
    who.require("admin")
    return _axis_form(request, who, machine_id)


@router.post("/machines/{machine_id}/axes", response_class=HTMLResponse)
async def add_axis(request: Request, machine_id: Id, who: Posted):
    who.require("admin")
    checked = cf.axis(await request.form())
    svc = _svc(request)
    if checked.value is None:
        return _axis_form(request, who, machine_id, checked, 422)
    try:
        st = axis_settings(checked.value, allow_link_local=svc.settings.limits.allow_link_local_controllers,
                           profiles_dir=svc.settings.profiles_path)
        with session_scope(svc.factory) as s:
            a = config_repo.create_axis(s, machine_id, st)
            s.commit()
            svc.axis_changed(a)
    except ConflictError as exc:
        checked.errors["name"] = str(exc)
        return _axis_form(request, who, machine_id, checked, 409)
    except MebmError as exc:
        msg = str(exc)
        where = "controller_url" if "controller_url" in msg else "cron" if "cron" in msg else ""
        checked.errors[where] = msg
        return _axis_form(request, who, machine_id, checked, 422)
    return back(f"/ui/config/axes/{a.id}", f"axis {a.name!r} added to {a.machine_name!r}: now add its machining tasks")


# -- tasks and schedule of an axis -----------------------------------------------------------------
def _axis_page(request: Request, who: Viewer, axis_id: int, *, msg: str | None = None,
               tasks_form: cf.Checked | None = None, schedule_form: cf.Checked | None = None,
               status_code: int = 200) -> HTMLResponse:
    svc = _svc(request)
    with session_scope(svc.factory) as s:
        axis = config_repo.get_axis(s, axis_id)
    sch = axis.settings.schedule
    rows = tasks_form.form["rows"] if tasks_form else [cf.row_of(t) for t in axis.tasks] + [cf.new_task_row()]
    sf = schedule_form.form if schedule_form else {
        "interval_s": "" if sch.interval_s is None else f"{sch.interval_s:g}", "cron": sch.cron or "",
        "enabled": sch.enabled}
    limits = {}
    for t in axis.tasks:
        try:
            limits[t.name] = t.backlash_limit_um()
        except MebmError:
            limits[t.name] = None
    task_errors = tasks_form.errors if tasks_form else {}
    row_errors: dict[int, list[str]] = {}
    for k, v in task_errors.items():  # "tasks.3.radius_mm" -> row 3: "radius_mm: ..."
        parts = k.split(".")
        if len(parts) >= 2 and parts[0] == "tasks":
            row_errors.setdefault(int(parts[1]), []).append(f"{parts[2]}: {v}" if len(parts) == 3 else v)
    return page(request, "config_axis.html", status_code, who=who, msg=msg, axis=axis, rows=rows, sf=sf,
                task_errors=task_errors, row_errors={i: "; ".join(v) for i, v in row_errors.items()},
                schedule_errors=schedule_form.errors if schedule_form else {},
                limits=limits, next_run=svc.scheduler.next_run(axis_id))


@router.get("/axes/{axis_id}", response_class=HTMLResponse)
def axis_config_page(request: Request, axis_id: Id, who: Who, msg: str | None = None):
    who.require("admin")
    return _axis_page(request, who, axis_id, msg=msg)


@router.post("/axes/{axis_id}/tasks", response_class=HTMLResponse)
async def put_tasks(request: Request, axis_id: Id, who: Posted):
    who.require("admin")
    checked, where = cf.tasks(await request.form())
    svc = _svc(request)
    if checked.value is None:
        return _axis_page(request, who, axis_id, tasks_form=checked, status_code=422)
    try:
        with session_scope(svc.factory) as s:
            axis = config_repo.get_axis(s, axis_id)
            a = config_repo.set_tasks(s, axis_id, machining_tasks(checked.value.tasks, axis.spec.position_gain_per_s))
            s.commit()
            svc.axis_changed(a)
    except MebmError as exc:  # a tolerance the model cannot map ("tasks[2]: ..."), duplicate names
        import re

        m = re.match(r"tasks\[(\d+)\]: (.*)", str(exc), re.S)
        checked.errors[f"tasks.{where[int(m.group(1))]}" if m else ""] = m.group(2) if m else str(exc)
        return _axis_page(request, who, axis_id, tasks_form=checked, status_code=422)
    return back(f"/ui/config/axes/{axis_id}", f"{len(a.tasks)} machining task(s) saved; the verdict follows them")


@router.post("/axes/{axis_id}/schedule", response_class=HTMLResponse)
async def put_schedule(request: Request, axis_id: Id, who: Posted):
    who.require("admin")
    checked = cf.schedule(await request.form())
    svc = _svc(request)
    if checked.value is None:
        return _axis_page(request, who, axis_id, schedule_form=checked, status_code=422)
    try:
        sch = schedule_of(checked.value)
        with session_scope(svc.factory) as s:
            a = config_repo.set_schedule(s, axis_id, sch)
            s.commit()
            svc.axis_changed(a)
    except MebmError as exc:  # a cron expression the scheduler cannot read
        checked.errors["cron"] = str(exc)
        return _axis_page(request, who, axis_id, schedule_form=checked, status_code=422)
    return back(f"/ui/config/axes/{axis_id}", "schedule saved")
