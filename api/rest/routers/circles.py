"""/machines/{id}/circles and /circles/{id}: circular tests (ISO 230-4), the direct
measurement of the machining error.

A test is posted in core.circle.io's JSON layout (operate). The service analyses it
(G, H, F, the reversal spikes, with U), compares each axis' spikes with Eq. 8's TBE at
the axis' latest b̄, judges each axis against its circle tasks at the test's radius and
feed, stores it and answers with all of it. A WARNING or ALARM raises the same alert
and work order as a round trip's decision, with the test as the evidence.
"""

from __future__ import annotations

from datetime import datetime, timedelta
from typing import Annotated, Any

from fastapi import APIRouter, Body, File, Form, Path, Query, Response, UploadFile, status
from fastapi.concurrency import run_in_threadpool

from api.rest.auth import OperateKey, ReadKey
from api.rest.deps import MachineId, ServiceDep, SessionDep
from api.service.circles import import_circular_test, record_circular_test
from core.circle import from_json, to_json
from core.errors import InputError
from storage.db import AlertRecord, CircularTestRecord, circles_repo, utcnow

router = APIRouter(tags=["circular tests"])
CircleId = Annotated[int, Path(ge=1, le=2**31 - 1, description="circular test id")]

EXAMPLE = {
    "radius_mm": 50.0, "feed_mm_min": 1000.0, "plane": ["x", "y"], "temperature_c": 20.5, "utility_day": 118.0,
    "source": "ballbar QC20-W, file vmc-850_xy.b5r",
    "instrument": {"kind": "ballbar", "resolution_um": 0.1, "accuracy_um": 0.5, "name": "QC20-W"},
    "passes": [{"direction": "ccw", "angle_deg": [0.0, 0.5, "..."], "radial_um": [0.4, 0.5, "..."]},
               {"direction": "cw", "angle_deg": [0.0, 359.5, "..."], "radial_um": [0.3, 0.2, "..."]}],
}


def _iso(t: datetime | None) -> str | None:
    return None if t is None else t.isoformat().replace("+00:00", "Z")


def circle_doc(r: CircularTestRecord, *, samples: bool = False) -> dict:
    """A stored test as the API answers it; ``samples``: with the passes (core.circle.io layout)."""
    doc = {
        "id": r.id, "machine_id": r.machine_id, "machine_name": r.machine_name, "plane": list(r.plane),
        "axis_ids": {name: r.axis_ids[i] for i, name in enumerate(r.plane)}, "radius_mm": r.radius_mm,
        "feed_mm_min": r.feed_mm_min, "directions": list(r.directions), "temperature_c": r.temperature_c,
        "utility_day": r.utility_day, "measured_at": _iso(r.measured_at), "recorded_at": _iso(r.recorded_at),
        "recorded_by": r.recorded_by, "source": r.source, "instrument": r.instrument, "state": r.state,
        "figures": r.figures, "agreement": r.agreement, "decision": r.decision,
        "href": f"/api/v1/circles/{r.id}",
    }
    if samples and r.test is not None:
        doc["test"] = to_json(r.test)
    return doc


def _alert_doc(a: AlertRecord) -> dict:
    return {"id": a.id, "axis_id": a.axis_id, "kind": a.kind, "active": a.active, "task_name": a.task_name,
            "tbe_um": a.tbe_um, "tolerance_um": a.tolerance_um, "raised_by_circular_test_id": a.raised_by_circular_test_id,
            "cleared_by_circular_test_id": a.cleared_by_circular_test_id, "message": a.message}


def _measured_at(body: dict) -> datetime | None:
    raw = body.get("measured_at")
    if raw is None:
        return None
    try:
        t = datetime.fromisoformat(str(raw).replace("Z", "+00:00"))
    except ValueError as exc:
        raise InputError(f"measured_at (={raw!r}) must be an ISO 8601 time, e.g. 2026-03-01T08:00:00Z") from exc
    if t.tzinfo is None:
        raise InputError(f"measured_at (={raw!r}) needs its time zone (e.g. a trailing Z for UTC)")
    if t > utcnow() + timedelta(minutes=5):  # (a controller's clock may run a little ahead)
        raise InputError(f"measured_at (={raw!r}) is in the future: give the time the test was run")
    return t


@router.post("/machines/{machine_id}/circles", response_model=dict[str, Any], status_code=status.HTTP_201_CREATED,
             summary="Post a circular test (operate): analysed, compared with the TBE at b̄, judged, stored")
async def post_circle(machine_id: MachineId, svc: ServiceDep, key: OperateKey, response: Response,
                      body: Annotated[dict[str, Any], Body(description="a circular test in core.circle.io's layout "
                                                                          "(units in the keys); measured_at optional",
                                                           examples=[EXAMPLE])]):
    def run():
        return _stored_doc(svc, machine_id, from_json(body), key.name, _measured_at(body))

    doc = await run_in_threadpool(run)
    response.headers["Location"] = doc["href"]
    return doc


def _stored_doc(svc, machine_id: int, test, by: str, measured_at) -> dict:
    """The test stored (analysed, compared, judged, alerted on) and its document with the
    alerts it raised or cleared."""
    stored = record_circular_test(svc, machine_id, test, by=by, measured_at=measured_at)
    doc = circle_doc(stored.record)
    doc["alerts"] = [_alert_doc(a) for a in stored.alerts]
    return doc


@router.post("/machines/{machine_id}/circles/import", response_model=dict[str, Any],
             status_code=status.HTTP_201_CREATED,
             summary="Import an exported circular test (operate): a CSV through a circle-import profile, then as POST "
                     "/machines/{id}/circles")
async def import_circle(
        machine_id: MachineId, svc: ServiceDep, key: OperateKey, response: Response,
        file: Annotated[UploadFile, File(description="the export: a ballbar's radial deviations or a trace tool's "
                                                     "positions (CSV)")],
        profile: Annotated[UploadFile, File(description="the circle-import profile (TOML, mebm-circle-profile/1; "
                                                        "examples/circle-profiles/)")],
        radius_mm: Annotated[float | None, Form(gt=0, le=1e5, description="the nominal radius, if not in the profile")] = None,
        feed_mm_min: Annotated[float | None, Form(gt=0, le=1e6, description="the feed, if not in the profile")] = None,
        plane: Annotated[str | None, Form(max_length=41, description="the two axes, first at 0°: xy or x,y")] = None,
        temperature_c: Annotated[float | None, Form(ge=-50, le=100)] = None,
        utility_day: Annotated[float | None, Form(ge=0, le=1e6)] = None,
        measured_at: Annotated[str | None, Form(max_length=40, description="ISO 8601 with a zone")] = None):
    raw, prof = await file.read(), await profile.read()

    def run():
        axes = None if plane is None else (plane.split(",") if "," in plane else plane)
        test = import_circular_test(raw, file.filename or "", prof, radius_mm=radius_mm, feed_mm_min=feed_mm_min,
                                    plane=axes, temperature_c=temperature_c, utility_day=utility_day)
        return _stored_doc(svc, machine_id, test, key.name, _measured_at({"measured_at": measured_at}))

    doc = await run_in_threadpool(run)
    response.headers["Location"] = doc["href"]
    return doc


@router.get("/machines/{machine_id}/circles", response_model=dict[str, Any],
            summary="A machine's circular tests, newest first (of one axis with axis=<name>)")
def list_circles(machine_id: MachineId, s: SessionDep, _k: ReadKey,
                 axis: Annotated[str | None, Query(max_length=20, description="an axis name of the machine")] = None,
                 limit: Annotated[int, Query(ge=1, le=500)] = 100, offset: Annotated[int, Query(ge=0, le=10**7)] = 0):
    rows = circles_repo.list_circular_tests(s, machine_id, axis, limit, offset=offset)
    total = circles_repo.count_circular_tests(s, machine_id, axis)
    return {"items": [circle_doc(r) for r in rows], "total": total, "limit": limit, "offset": offset}


@router.get("/circles/{circle_id}", response_model=dict[str, Any],
            summary="A circular test: figures, agreement, decision and (samples=true) the passes")
def get_circle(circle_id: CircleId, s: SessionDep, _k: ReadKey,
               samples: Annotated[bool, Query(description="include the passes' angle_deg/radial_um")] = True):
    return circle_doc(circles_repo.get_circular_test(s, circle_id), samples=samples)
