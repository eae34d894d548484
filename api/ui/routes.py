"""The dashboard's routes under /ui (server-rendered HTML, Jinja2)."""

from __future__ import annotations

import logging
from pathlib import Path as FsPath
from typing import Annotated, Literal

from fastapi import APIRouter, Depends, Form, Path, Query, Request
from fastapi.concurrency import run_in_threadpool
from fastapi.responses import HTMLResponse, RedirectResponse, Response
from fastapi.templating import Jinja2Templates

from api.service.figures import axis as axis_figures
from api.service.figures import plots
from api.service.figures.gate import RenderBusy
from api.service.gap_jobs import (RESIDUALS, TooFewRuns, TooManyJobs, age_s, axis_job, axis_plan, repairs_of,
                                  run_bytes, runs_stored_since)
from api.service.throttle import failed_authentication
from api.ui import format as fmt
from api.ui import panels as axis_panels
from api.ui import views
from api.ui.sessions import PRE_CSRF_COOKIE, ROLE_RANK, SESSION_COOKIE, Session, UiState, same_token
from storage.dataset import FolderOwnerError
from storage.db import ConflictError, NotFoundError, config_repo, maintenance_repo, results_repo, session_scope

log = logging.getLogger("mebm.ui")
HERE = FsPath(__file__).parent
templates = Jinja2Templates(directory=str(HERE / "templates"))
templates.env.filters.update(um=fmt.um, age=fmt.age, when=fmt.when, pct=fmt.pct, duration=fmt.duration)
templates.env.globals.update(due=fmt.due)
templates.env.globals.update(state_class=fmt.state_class, restore_below_explanation=fmt.restore_below_explanation)
router = APIRouter(prefix="/ui", include_in_schema=False)
GAP_RUNS = 16
POLL_S = 5
# a database id, as the REST API bounds it (positive 31-bit, PostgreSQL integer): anything
# else is a 422 page naming it, never an overflow in the database driver (a 500)
Id = Annotated[int, Path(ge=1, le=2**31 - 1)]
JobId = Annotated[int | None, Query(ge=1, le=2**31 - 1)]


class SignInRequired(Exception):
    """No valid session: pages redirect to the sign-in form, fragments answer 401."""


class UiForbidden(Exception):
    def __init__(self, message: str):
        super().__init__(message)
        self.message = message


def ui_state(request: Request) -> UiState:
    return request.app.state.ui


class Viewer:
    """The signed-in user: the key record (roles as in the API) and the session."""

    def __init__(self, session: Session):
        self.session, self.key, self.sid = session, session.key, session.token

    @property
    def csrf(self) -> str:
        return self.session.csrf

    def can(self, role: str) -> bool:
        return ROLE_RANK[self.key.role] >= ROLE_RANK[role]

    def require(self, role: str) -> None:
        if not self.can(role):
            raise UiForbidden(f"key {self.key.name!r} has role {self.key.role!r}; this needs {role!r}")


async def viewer(request: Request) -> Viewer:
    # the session and its key in one query: a revoked key or an expired session is no session
    sess = await run_in_threadpool(ui_state(request).sessions.get, request.cookies.get(SESSION_COOKIE))
    if sess is None:
        raise SignInRequired()
    return Viewer(sess)


async def csrf_checked(request: Request, who: Annotated[Viewer, Depends(viewer)]) -> Viewer:
    form = await request.form()
    if not same_token(form.get("csrf"), who.csrf):
        raise UiForbidden("the form's CSRF token is missing or wrong: reload the page and try again")
    return who


Who = Annotated[Viewer, Depends(viewer)]
Posted = Annotated[Viewer, Depends(csrf_checked)]


def page(request: Request, name: str, status_code: int = 200, **ctx) -> HTMLResponse:
    return templates.TemplateResponse(request, name, {"poll_s": POLL_S, **ctx}, status_code=status_code)


def back(url: str, msg: str | None = None) -> RedirectResponse:
    from urllib.parse import quote

    return RedirectResponse(url + (f"?msg={quote(msg)}" if msg else ""), status_code=303)


def set_session_cookie(resp: Response, sid: str, request: Request) -> None:
    resp.set_cookie(SESSION_COOKIE, sid, httponly=True, samesite="strict", path="/",
                    secure=request.url.scheme == "https")


def _signed_in(request: Request, sess: Session) -> Response:
    # a page that moves on by itself (a same-site navigation, so the Strict cookie is sent),
    # rather than a redirect at the end of a possibly cross-site navigation from a terminal
    resp = page(request, "signed_in.html")
    set_session_cookie(resp, sess.token, request)
    resp.delete_cookie(PRE_CSRF_COOKIE, path="/ui")
    return resp


def _pre_csrf_page(request: Request, name: str, status_code: int = 200, **ctx) -> HTMLResponse:
    """A page with a form posted before there is a session: a double-submit CSRF token
    (an HttpOnly, Strict cookie and the same value in a hidden field)."""
    import secrets

    token = secrets.token_urlsafe(24)
    resp = page(request, name, status_code, csrf=token, who=None, **ctx)
    resp.set_cookie(PRE_CSRF_COOKIE, token, httponly=True, samesite="strict", path="/ui",
                    secure=request.url.scheme == "https")
    return resp


def _pre_csrf_ok(request: Request, sent: str) -> bool:
    return same_token(sent, request.cookies.get(PRE_CSRF_COOKIE))


def _refused_pre_csrf(request: Request) -> HTMLResponse:
    return page(request, "error.html", 403, who=None, title="Refused",
                message="the sign-in form's CSRF token is missing or wrong: reload the sign-in page")


LINK_REFUSED = ("this sign-in link has already been used, has expired (links last 10 minutes) or its key was "
                "revoked. Sign in with a key instead.")


# -- sign-in / sign-out -----------------------------------------------------------------------
@router.get("/sign-in", response_class=HTMLResponse)
def sign_in_form(request: Request, msg: str | None = None):
    return _pre_csrf_page(request, "sign_in.html", msg=msg)


@router.post("/sign-in", response_class=HTMLResponse)
async def sign_in(request: Request, key: Annotated[str, Form(max_length=200)] = "",
                  csrf: Annotated[str, Form(max_length=200)] = ""):
    if not _pre_csrf_ok(request, csrf):
        return _refused_pre_csrf(request)
    state = request.app.state
    secret = key.strip()
    # the key is looked up first: a valid key signs in even from a throttled address
    rec = await run_in_threadpool(state.key_cache.lookup, state.service.factory, secret) if secret else None
    if rec is None:
        wait_s = failed_authentication(request, secret, "dashboard sign-in", log)
        if wait_s > 0:
            return page(request, "error.html", 429, who=None, title="Too many attempts",
                        message=f"too many failed sign-ins from this address; try again in {wait_s:.0f} s")
        return back("/ui/sign-in", "unknown or revoked key")
    return _signed_in(request, await run_in_threadpool(ui_state(request).sessions.open, rec))


@router.get("/sign-in/{token}", response_class=HTMLResponse)
async def sign_in_link_page(request: Request, token: Annotated[str, Path(max_length=100)]):
    """Opening a link spends nothing (link previews fetch it): a button posts it."""
    rec = await run_in_threadpool(ui_state(request).sessions.peek_link, token)
    if rec is None:
        return page(request, "error.html", 403, who=None, title="Sign-in link refused", message=LINK_REFUSED)
    return _pre_csrf_page(request, "sign_in_link.html", link_key=rec)


@router.post("/sign-in/{token}", response_class=HTMLResponse)
async def sign_in_link(request: Request, token: Annotated[str, Path(max_length=100)],
                       csrf: Annotated[str, Form(max_length=200)] = ""):
    if not _pre_csrf_ok(request, csrf):
        return _refused_pre_csrf(request)  # the link is not spent
    sess = await run_in_threadpool(ui_state(request).sessions.redeem_link, token)
    if sess is None:
        return page(request, "error.html", 403, who=None, title="Sign-in link refused", message=LINK_REFUSED)
    return _signed_in(request, sess)


@router.post("/sign-out")
def sign_out(request: Request, who: Posted):
    ui_state(request).sessions.close(who.sid)
    resp = back("/ui/sign-in", "signed out")
    resp.delete_cookie(SESSION_COOKIE, path="/")
    return resp


# -- fleet ------------------------------------------------------------------------------------
def _fleet(request: Request):
    svc = request.app.state.service
    with session_scope(svc.factory) as s:
        return views.fleet(svc, s)


@router.get("/", response_class=HTMLResponse)
def fleet_page(request: Request, who: Who, msg: str | None = None):
    return page(request, "fleet.html", who=who, fleet=_fleet(request), msg=msg)


@router.get("/fleet.frag", response_class=HTMLResponse)
def fleet_fragment(request: Request, who: Who):
    return page(request, "_fleet.html", who=who, fleet=_fleet(request))


@router.post("/alerts/{alert_id}/ack")
def acknowledge(request: Request, alert_id: Id, who: Posted):
    who.require("operate")
    svc = request.app.state.service
    with session_scope(svc.factory) as s:
        a = results_repo.acknowledge_alert(s, alert_id, who.key.name)
        order = maintenance_repo.active_order(s, a.axis_id)
    msg = f"alert {a.id} acknowledged by {who.key.name}"
    if order is not None and order.alert_id == a.id:  # the alert was seen; the repair is the order's
        msg += (f"; the repair is followed by work order {order.id} ({order.state}), "
                f"in the Maintenance section of the axis page")
    return back("/ui/", msg)


# -- axis -------------------------------------------------------------------------------------
def axis_ctx(request: Request, axis_id: int, range_: str, *, panels: bool = False) -> dict:
    svc = request.app.state.service
    with session_scope(svc.factory) as s:
        axis = config_repo.get_axis(s, axis_id)
        _, cycles = results_repo.list_measurements(s, axis_id, limit=12)
        extra = axis_panels.render_context(svc, s, axis_id) if panels else []
    now = views.utcnow()
    row = views.axis_row(svc.status.get(axis_id), svc.scheduler.next_run(axis_id), now)
    return {"axis": axis, "row": row, "now": now, "cycles": cycles, "range": range_ if range_ in views.RANGES else "90d",
            "ranges": list(views.RANGES), "panels": extra}


@router.get("/axes/{axis_id}", response_class=HTMLResponse)
def axis_page(request: Request, axis_id: Id, who: Who, range: str = "90d", msg: str | None = None):  # noqa: A002
    return page(request, "axis.html", who=who, msg=msg, **axis_ctx(request, axis_id, range, panels=True))


@router.get("/axes/{axis_id}/part/{part}.frag", response_class=HTMLResponse)
def axis_fragment(request: Request, axis_id: Id, part: Literal["verdict", "cycles"], who: Who):
    return page(request, f"_axis_{part}.html", who=who, **axis_ctx(request, axis_id, "90d"))


@router.get("/axes/{axis_id}/plots/{name}.png")
async def axis_plot(request: Request, axis_id: Id, name: str, who: Who, range: str = "90d",  # noqa: A002
                    direction: Annotated[str, Query(pattern="^(positive|negative)$")] = "positive"):
    if name not in axis_figures.NAMES:
        raise NotFoundError("figure", name)
    svc = request.app.state.service
    # the service's figure cache (shared with the REST plots) knows what each figure is drawn
    # from; the range starts on the hour, so that a figure is drawn once an hour at most
    # while no measurement comes
    since = views.since_of(range, views.utcnow().replace(minute=0, second=0, microsecond=0))

    def render() -> bytes:  # through the service's render gate, as the REST plots (limits.plot_*)
        st = svc.status.get(axis_id)
        with session_scope(svc.factory) as s:
            return axis_figures.render(s, axis_id, name, direction=direction, since=since, status=st,
                                       draw=svc.plots.draw, cache=svc.figures)

    try:
        png = await svc.render_gate.run(render)
    except RenderBusy as exc:
        wait_s = max(1, round(exc.retry_after_s))
        return Response(str(exc), status_code=429, media_type="text/plain", headers={"Retry-After": str(wait_s)})
    return Response(png, media_type="image/png", headers={"Cache-Control": "no-cache"})


@router.get("/axes/{axis_id}/history.csv")
def history_csv(request: Request, axis_id: Id, who: Who, range: str = "all"):  # noqa: A002
    svc = request.app.state.service
    with session_scope(svc.factory) as s:
        axis = config_repo.get_axis(s, axis_id)
        text = views.history_csv(s, axis_id, views.since_of(range))
    stem = "".join(c if c.isalnum() or c in "-_" else "_" for c in f"{axis.machine_name}_{axis.name}_{range}")
    return Response(text, media_type="text/csv",
                    headers={"Content-Disposition": f'attachment; filename="{stem}_history.csv"'})


@router.post("/axes/{axis_id}/measure")
def measure_now(request: Request, axis_id: Id, who: Posted):
    who.require("operate")
    state = request.app.state
    wait_s = state.trigger_limit.take(who.key.name)
    if wait_s > 0:
        return back(f"/ui/axes/{axis_id}", f"too many measurements triggered; retry in {wait_s:.0f} s")
    state.service.trigger(axis_id, who.key.name)
    return back(f"/ui/axes/{axis_id}", "measurement queued: it runs after any cycle of this axis already running")


# -- gap --------------------------------------------------------------------------------------
def _gap_folder(request: Request, axis_id: int):
    svc = request.app.state.service
    with session_scope(svc.factory) as s:
        axis = config_repo.get_axis(s, axis_id)
    try:  # only the axis' own runs: never a folder another machine (of another database) wrote
        return axis, (svc.executor.readable_folder(axis) if svc.executor is not None else None), None
    except FolderOwnerError as exc:
        return axis, None, str(exc)


def _gap_refusal(jobs) -> str:
    """Why a start was refused, as the queue is now (and what to do)."""
    pending = jobs.pending_jobs()
    if len(pending) < jobs.max_pending:
        return "The queue was full when the diagnosis was asked for; it has room now: start it again."
    first = min(jobs.progress(j).get("remaining_s", 0.0) for j in pending)
    return (f"The service is computing {len(pending)} gap diagnoses, the most it runs at once, so this one was "
            f"not started. The first is expected to end in about {fmt.duration(first)}: start this one again then.")


def _gap_ctx(request: Request, axis_id: int, job_id: int | None = None) -> dict:
    """The state of the gap page: the job ``job_id`` it follows (else the axis' pending job,
    else its newest finished one), always with an answer or a reason."""
    jobs = request.app.state.service.gap_jobs
    axis, folder, refusal = _gap_folder(request, axis_id)
    base = {"axis": axis, "runs": GAP_RUNS, "timeout_s": jobs.timeout_s}
    if refusal is not None:
        return {**base, "gap": "failed", "detail": refusal}
    if folder is None or not (folder / "dataset.json").is_file():
        return {**base, "gap": "no_runs", "detail": "no stored runs to diagnose yet: the first good measurement of "
                                                    "the axis stores one"}
    # the runs a diagnosis started now would use (since the last repair), shown before it starts
    try:
        plan = axis_plan(folder, axis_id, GAP_RUNS, repairs_of(request.app.state.service.factory, axis_id))
        base.update(plan=plan.to_dict(), plan_files=plan.files, plan_text=plan.text(), runs=plan.runs)
    except TooFewRuns as exc:
        base.update(plan=None, plan_error=str(exc))
    if job_id is not None:
        job = jobs.job(job_id)
        if job is None or job.key[0] != str(folder.resolve()):
            return {**base, "gap": "lost", "detail": "this diagnosis is no longer known to the service (it restarted "
                                                     "since, or dropped the answer from its memory). Start it again"}
        jobs.ask(job)
    else:
        job = axis_job(jobs, axis_id, folder, GAP_RUNS, start=False)
        if job is None:
            return {**base, "gap": "idle"}
    p = jobs.progress(job)
    ctx = {**base, "job": p, "runs": job.runs}
    if p["state"] in ("queued", "running"):
        return {**ctx, "gap": p["state"]}
    err = job.error()
    if err is not None:
        return {**ctx, "gap": "failed", "detail": str(err) or "the job was dropped; start it again"}
    report = job.future.result()
    return {**ctx, "gap": "done", "report": report, "age_s": age_s(report),
            "stored_since": runs_stored_since(folder, report)}


def _gap_url(axis_id: int, job_id: int | None = None, *, frag: bool = False, **query) -> str:
    from urllib.parse import urlencode

    q = {**({"job": job_id} if job_id is not None else {}), **{k: v for k, v in query.items() if v is not None}}
    return f"/ui/axes/{axis_id}/gap{'.frag' if frag else ''}" + (f"?{urlencode(q)}" if q else "")


@router.get("/axes/{axis_id}/gap", response_class=HTMLResponse)
def gap_page(request: Request, axis_id: Id, who: Who, msg: str | None = None, job: JobId = None,
             refused: int = 0):
    ctx = _gap_ctx(request, axis_id, job)
    jobs = request.app.state.service.gap_jobs
    _axis, folder, _refusal = _gap_folder(request, axis_id)  # the promise: the expected time of the runs it would use
    files = ctx.get("plan_files")
    ctx.update(expected_s=jobs.expected_s(ctx["runs"], run_bytes(folder, files or GAP_RUNS)
                                          if folder is not None and ctx["gap"] != "no_runs" else None),
               timed=jobs.s_per_run is not None)
    if refused and ctx["gap"] not in ("queued", "running"):
        ctx["refused"] = _gap_refusal(request.app.state.service.gap_jobs)
    job_id = ctx["job"]["id"] if ctx.get("job") else None
    return page(request, "gap.html", who=who, msg=msg, poll_url=_gap_url(axis_id, job_id, frag=True), **ctx)


@router.get("/axes/{axis_id}/gap.frag", response_class=HTMLResponse)
def gap_fragment(request: Request, axis_id: Id, who: Who, job: JobId = None):
    return page(request, "_gap.html", who=who, **_gap_ctx(request, axis_id, job))


@router.get("/axes/{axis_id}/gap/residuals/{index}.png")
def gap_residual_plot(request: Request, axis_id: Id, index: Annotated[int, Path(ge=0, le=10_000)], who: Who,
                      job: JobId = None):
    """Measured vs model on one test run of the axis' finished diagnosis, before and
    after the diagnosed effect (the figure of ``mebm gap diagnose --plots``)."""
    ctx = _gap_ctx(request, axis_id, job)
    curves = ctx["report"].get(RESIDUALS, []) if ctx["gap"] == "done" else []
    if not 0 <= index < len(curves):
        raise NotFoundError(f"residual plot of the diagnosis of axis {axis_id}", index)
    r = ctx["report"]
    key = (axis_id, "gap", tuple(r.get("runs_used", ())), r.get("gap_before_um"), index)
    svc = request.app.state.service
    png = svc.figures.get_or_render(key, lambda: svc.plots.draw(plots.gap_residual, curves[index], r["effect"]))
    return Response(png, media_type="image/png", headers={"Cache-Control": "no-cache"})


@router.post("/axes/{axis_id}/gap")
def gap_start(request: Request, axis_id: Id, who: Posted):
    """Start (or join) the diagnosis of the axis' newest runs; the page then follows that job."""
    jobs = request.app.state.service.gap_jobs
    _axis, folder, refusal = _gap_folder(request, axis_id)
    if refusal is not None:
        return back(f"/ui/axes/{axis_id}/gap", refusal)
    try:
        job = axis_job(jobs, axis_id, folder, GAP_RUNS, fresh=True,
                       repairs=repairs_of(request.app.state.service.factory, axis_id))
    except TooManyJobs:  # the page says why, as the queue is when it is shown
        return RedirectResponse(_gap_url(axis_id, refused=1), status_code=303)
    except TooFewRuns as exc:
        return back(f"/ui/axes/{axis_id}/gap", str(exc))
    except NotFoundError as exc:
        if exc.kind == "axis":
            raise
        return back(f"/ui/axes/{axis_id}/gap", "no stored runs to diagnose yet")
    return RedirectResponse(_gap_url(axis_id, job.id), status_code=303)


# -- keys (admin) -----------------------------------------------------------------------------
def _keys_page(request: Request, who: Viewer, *, created: tuple | None = None, error: str | None = None,
               msg: str | None = None, status_code: int = 200, name: str = "", role: str = "read") -> HTMLResponse:
    svc = request.app.state.service
    with session_scope(svc.factory) as s:
        keys = config_repo.list_keys(s)
    return page(request, "keys.html", status_code, who=who, keys=keys, created=created, error=error, msg=msg,
                form_name=name, form_role=role)


@router.get("/keys", response_class=HTMLResponse)
def keys_page(request: Request, who: Who, msg: str | None = None):
    who.require("admin")
    return _keys_page(request, who, msg=msg)


@router.post("/keys", response_class=HTMLResponse)
async def create_key(request: Request, who: Posted):
    who.require("admin")
    form = await request.form()
    name, role = str(form.get("name", "")).strip(), str(form.get("role", ""))
    error = None
    if not 1 <= len(name) <= 100:
        error = "name: 1 to 100 characters, not blank"
    elif role not in ROLE_RANK:
        error = "role: one of read, operate, admin"
    if error:
        return _keys_page(request, who, error=error, status_code=422, name=name, role=role)
    svc = request.app.state.service
    try:
        with session_scope(svc.factory) as s:
            rec, secret = config_repo.create_key(s, name, role)
    except ConflictError as exc:
        return _keys_page(request, who, error=f"name: {exc}", status_code=409, name=name, role=role)
    # the secret is shown in this response only (never stored, never in a URL)
    resp = _keys_page(request, who, created=(rec, secret))
    resp.headers["Cache-Control"] = "no-store"
    return resp


@router.post("/keys/{key_id}/revoke")
def revoke_key(request: Request, key_id: Id, who: Posted):
    who.require("admin")
    if key_id == who.key.id:
        return back("/ui/keys", "a key cannot revoke itself: sign in with another admin key")
    svc = request.app.state.service
    with session_scope(svc.factory) as s:
        rec = config_repo.revoke_key(s, key_id)
    request.app.state.key_cache.clear()  # the API refuses it at once; its dashboard sessions ended with it
    return back("/ui/keys", f"key {rec.name!r} revoked")
