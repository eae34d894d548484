"""The maintenance loop on the dashboard: the axis page's work-order panel
(registered in api/ui/panels.py), its forms (acknowledge, record a repair, cancel) and
the fleet's maintenance page with the managers' summary.

The forms read into the REST API's request models (``api.service.maintenance.input``)
and call the same service functions as the REST routes (``svc.maintenance``:
``record_repair``, ``transition``), so a value or a step refused by one is refused by
the other with the same message. An operate key is needed to post (a read key sees no
form, and the server refuses it with 403 anyway); every form carries the session's CSRF
token. A refusal comes back as the axis page with the message next to the form.
"""

from __future__ import annotations

from urllib.parse import quote

from typing import Annotated

from fastapi import APIRouter, Path, Query, Request
from fastapi.concurrency import run_in_threadpool
from fastapi.responses import HTMLResponse, RedirectResponse, Response
from pydantic import ValidationError

from api.service.maintenance.input import NoteIn, RepairIn, summary_csv, summary_rows
from api.ui import format as fmt
from api.ui import panels
from api.ui.config_forms import field_errors
from api.ui.routes import Posted, Viewer, Who, axis_ctx, page, templates
from core.criteria import criterion_label
from core.errors import InputError
from core.maintenance import REPAIR_KINDS, TransitionError
from storage.db import NotFoundError, config_repo, maintenance_repo, results_repo, session_scope

router = APIRouter(prefix="/ui", include_in_schema=False)
Id = Annotated[int, Path(ge=1, le=2**31 - 1)]  # a database id: anything else is a 422, not an overflow
TEMPLATE = "_axis_maintenance.html"
REPAIR_FIELDS = ("kind", "note", "performed_at", "compensation_measurement_id", "compensation_file")
KIND_WORDS = {"corrective": "corrective", "condition_based": "condition-based"}  # EN 13306
REPAIR_WORDS = {"preload_adjusted": "preload adjusted", "nut_replaced": "nut replaced",
                "screw_replaced": "screw replaced", "compensation_loaded": "compensation table loaded",
                "lubricated": "lubricated", "other": "other"}
LEAD_WORDS = {key: (criterion_label(key)[:1].upper() + criterion_label(key)[1:], unit)  # ISO 3408-3's names
              for key, unit in (("e_p_um_per_1000mm", "µm/1000 mm"), ("v_u_um", "µm"), ("v_300_um", "µm"),
                                ("v_2pi_um", "µm"))}
RECENT_REPAIRS = 5
templates.env.globals.update(recommendation_without_restore=fmt.recommendation_without_restore)


# -- the axis page's panel ----------------------------------------------------------------------
def _num(v, nd: int = 1) -> str:
    return "–" if v is None else f"{v:.{nd}f}"


def verification_rows(v: dict) -> list[dict]:
    """The before/after table of a verification (core.maintenance.Verification.to_dict):
    one row per quantity, with the change and its expanded uncertainty (k = 2)."""
    before, after = v.get("before", {}), v.get("after", {})
    tb = {t["task"]: t for t in before.get("tasks", [])}
    ta = {t["task"]: t for t in after.get("tasks", [])}
    rows = []
    for key, c in v.get("changes", {}).items():
        if key == "backlash_mean_um":
            label, unit, nd = "Mean backlash b̄", "µm", 1
            b = f"{_num(c['before'])} ± {_num(before.get('backlash_mean_uncertainty_um'))}"
            a = f"{_num(c['after'])} ± {_num(after.get('backlash_mean_uncertainty_um'))}"
        elif key.startswith("tbe_um["):
            task = key[len("tbe_um["):-1]
            label, unit, nd = f"TBE of {task}", "µm", 2
            b = f"{_num(c['before'], 2)} ± {_num(tb.get(task, {}).get('tbe_uncertainty_um'), 2)}"
            a = f"{_num(c['after'], 2)} ± {_num(ta.get(task, {}).get('tbe_uncertainty_um'), 2)}"
        else:
            label, unit = LEAD_WORDS.get(key, (key, "µm"))
            nd = 2
            b, a = _num(c["before"], 2), _num(c["after"], 2)
        change = "–" if c.get("change") is None else f"{c['change']:+.{nd}f}"
        if c.get("uncertainty"):
            change += f" ± {c['uncertainty']:.{nd}f}"
        rows.append({"key": key, "label": label, "unit": unit, "before": b, "after": a, "change": change,
                     "significant": c.get("significant")})
    return rows


def _verification_cycle(s, order) -> object | None:
    if order is None or order.verification_measurement_id is None:
        return None
    try:
        return results_repo.get_measurement(s, order.verification_measurement_id, curves=False)[0]
    except NotFoundError:  # a purged cycle: the order still shows its id
        return None


def panel_context(svc, s, axis_id: int) -> dict:
    order = maintenance_repo.active_order(s, axis_id)
    _, recent = maintenance_repo.list_orders(s, "all", axis_id=axis_id, limit=20)
    verified = next((o for o in recent if o.verification), None)  # the last verification, passed or not
    repairs = maintenance_repo.list_repairs(s, axis_id)[-RECENT_REPAIRS:][::-1]
    return {
        "order": order, "verification_cycle": _verification_cycle(s, order),
        "last": verified, "last_rows": verification_rows(verified.verification) if verified else [],
        "closed": next((o for o in recent if not o.active), None),
        "repairs": repairs, "kinds": REPAIR_KINDS, "kind_words": KIND_WORDS, "repair_words": REPAIR_WORDS,
        "verify_at": svc.maintenance.settings.verify_at, "enabled": svc.maintenance.settings.enabled,
        "form": {f: "" for f in REPAIR_FIELDS}, "errors": {}, "cancel_note": "",
    }


panels.register_axis_panel(panels.AxisPanel(TEMPLATE, panel_context))


@router.get("/axes/{axis_id}/maintenance/verification.frag", response_class=HTMLResponse)
def verification_fragment(request: Request, axis_id: Id, who: Who,
                          order: Annotated[int, Query(ge=1, le=2**31 - 1)]):
    """The repaired order's verification line, polled until its measurement is done."""
    svc = request.app.state.service
    with session_scope(svc.factory) as s:
        o = maintenance_repo.get_order(s, order)
        if o.axis_id != axis_id:
            raise NotFoundError(f"work order of axis {axis_id}", order)
        vc = _verification_cycle(s, o)
    return page(request, "_maintenance_verification.html", who=who, o=o, vc=vc, order_id=o.id, axis_id=axis_id,
                verify_at=svc.maintenance.settings.verify_at)


# -- the forms ------------------------------------------------------------------------------
def _to_axis(axis_id: int, msg: str) -> RedirectResponse:
    return RedirectResponse(f"/ui/axes/{axis_id}?msg={quote(msg)}#maintenance", status_code=303)


def _refused(request: Request, who: Viewer, axis_id: int, status_code: int, **panel) -> HTMLResponse:
    """The axis page again, with the form as sent and its messages in the panel."""
    ctx = axis_ctx(request, axis_id, "90d", panels=True)
    ctx["panels"] = [(name, {**p, **panel} if name == TEMPLATE else p) for name, p in ctx["panels"]]
    return page(request, "axis.html", status_code, who=who, msg=None, **ctx)


def _text(form, name: str) -> str:
    v = form.get(name, "")
    return v.strip() if isinstance(v, str) else ""


@router.post("/axes/{axis_id}/repairs", response_class=HTMLResponse)
async def record_repair(request: Request, axis_id: Id, who: Posted):
    who.require("operate")
    form = await request.form()
    sent = {f: _text(form, f) for f in REPAIR_FIELDS}
    body = {k: v for k, v in sent.items() if v != "" or k == "note"}
    try:
        rep = RepairIn(**body)
    except ValidationError as exc:
        errors = field_errors(exc)
        if "kind" in errors and sent["kind"] == "":
            errors["kind"] = "choose what was done"
        return await run_in_threadpool(_refused, request, who, axis_id, 422, form=sent, errors=errors)
    svc = request.app.state.service

    def run():
        return svc.maintenance.record_repair(
            axis_id, rep.kind, by=who.key.name, note=rep.note, performed_at=rep.performed_at,
            compensation_measurement_id=rep.compensation_measurement_id, compensation_file=rep.compensation_file)

    try:
        repair, order = await run_in_threadpool(run)
    except InputError as exc:  # the storage's rules: a time in the future, a table of another axis, ...
        msg = str(exc)
        where = next((f for f in ("performed_at", "compensation_measurement_id") if f in msg), "repair")
        return await run_in_threadpool(_refused, request, who, axis_id, 422, form=sent, errors={where: msg})
    what = f"repair {repair.id} ({REPAIR_WORDS[repair.kind]}) recorded by {who.key.name}"
    if order is None:
        return _to_axis(axis_id, what + "; the axis had no active work order, so nothing is verified")
    queued = (f"verification measurement {order.verification_measurement_id} queued"
              if order.verification_measurement_id else
              f"verification measurement at {svc.maintenance.settings.verify_at} UTC")
    return _to_axis(axis_id, f"{what}: work order {order.id} is {order.state}, {queued}")


async def _step(request: Request, who: Viewer, order_id: int, action: str, note: str):
    svc = request.app.state.service

    def axis_of() -> int:
        with session_scope(svc.factory) as s:
            return maintenance_repo.get_order(s, order_id).axis_id  # an unknown order: the 404 page

    axis_id = await run_in_threadpool(axis_of)
    err_key = "ack" if action == "acknowledge" else "cancel"
    try:
        NoteIn(note=note)
        order = await run_in_threadpool(lambda: svc.maintenance.transition(order_id, action, by=who.key.name,
                                                                           note=note))
    except ValidationError as exc:
        return await run_in_threadpool(_refused, request, who, axis_id, 422, cancel_note=note,
                                       errors={err_key: "note: " + field_errors(exc).get("note", "invalid")})
    except TransitionError as exc:  # the order's state forbids the step (the REST API's 409)
        return await run_in_threadpool(_refused, request, who, axis_id, 409, cancel_note=note,
                                       errors={err_key: str(exc)})
    except InputError as exc:  # a cancel without its reason
        return await run_in_threadpool(_refused, request, who, axis_id, 422, cancel_note=note,
                                       errors={err_key: str(exc)})
    return _to_axis(axis_id, f"work order {order.id} {order.state} by {who.key.name}")


@router.post("/maintenance/orders/{order_id}/ack", response_class=HTMLResponse)
async def acknowledge(request: Request, order_id: Id, who: Posted):
    who.require("operate")
    return await _step(request, who, order_id, "acknowledge", _text(await request.form(), "note"))


@router.post("/maintenance/orders/{order_id}/cancel", response_class=HTMLResponse)
async def cancel(request: Request, order_id: Id, who: Posted):
    who.require("operate")
    return await _step(request, who, order_id, "cancel", _text(await request.form(), "note"))


# -- the fleet's maintenance page ------------------------------------------------------------------
def _fleet_orders(svc) -> list[tuple]:
    with session_scope(svc.factory) as s:
        names = {a.id: (a.machine_name, a.name) for a in config_repo.list_axes(s)}
        _, active = maintenance_repo.list_orders(s, "active", limit=200)
        _, closed = maintenance_repo.list_orders(s, "closed", limit=10)
    return [(o, *names.get(o.axis_id, ("?", f"axis {o.axis_id}"))) for o in active], \
        [(o, *names.get(o.axis_id, ("?", f"axis {o.axis_id}"))) for o in closed]


@router.get("/maintenance", response_class=HTMLResponse)
def maintenance_page(request: Request, who: Who):
    svc = request.app.state.service
    active, closed = _fleet_orders(svc)
    axes, fleet = svc.maintenance.summary()
    return page(request, "maintenance.html", who=who, active=active, closed=closed, rows=summary_rows(axes),
                fleet=fleet, kind_words=KIND_WORDS, fixed_days=svc.maintenance.settings.fixed_interval_days)


@router.get("/maintenance/summary.csv")
def maintenance_csv(request: Request, who: Who):
    axes, fleet = request.app.state.service.maintenance.summary()
    return Response(summary_csv(summary_rows(axes), fleet), media_type="text/csv",
                    headers={"Content-Disposition": 'attachment; filename="maintenance-summary.csv"'})
