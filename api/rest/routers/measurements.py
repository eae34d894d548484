"""/measurements/{id}: one cycle with its criteria, TBE, curves and uncertainty."""

from __future__ import annotations

from typing import Annotated

from fastapi import APIRouter, Query

from api.rest import convert, schemas as sc
from api.rest.auth import ReadKey
from api.rest.deps import MeasurementId, ServiceDep, SessionDep
from storage.db import results_repo

router = APIRouter(tags=["measurements"])


@router.get("/measurements/{measurement_id}", response_model=sc.MeasurementDetail,
            summary="A measurement: status, criteria per direction, TBE per task, b(x) and lead curves")
def get_measurement(measurement_id: MeasurementId, s: SessionDep, svc: ServiceDep, _k: ReadKey,
                    curves: Annotated[bool, Query(description="include the b(x) and lead-deviation curves")] = True):
    c, r = results_repo.get_measurement(s, measurement_id, curves=curves)
    return convert.detail(c, r, curves, svc.executor.held() if svc.executor is not None else None)
