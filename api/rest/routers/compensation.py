"""/axes/{id}/compensation: the axis' last measurement as the controller's compensation table.

The table is computed from the raw round trip the service kept for the newest stored
measurement (the axis' dataset folder, or the ``@<time>`` folder begun when its
mechanics changed), analysed as the live cycle analysed it. 404: the axis has no
measurement yet; 409: the measurement's raw run is not there to use (not kept, removed
by retention) or the axis closes its loop on the linear scale. Formats and sign
conventions: docs/compensation.md.
"""

from __future__ import annotations

from enum import Enum
from pathlib import Path
from typing import Annotated

from fastapi import APIRouter, Query, Response

from api.rest.auth import ReadKey
from api.rest.deps import AxisId, ServiceDep, SessionDep
from api.service.compensation import LoopOnScaleError, export, load_round_trip
from api.service.cycles.runner import analyse
from core.criteria.uncertainty import inputs_of_spec
from core.errors import DatasetError
from storage.dataset import read_dataset
from storage.db import ConflictError, NotFoundError, config_repo, results_repo

router = APIRouter(tags=["compensation"])
TABLE = {200: {"content": {"text/plain": {}, "text/csv": {}},
               "description": "the table as a file (Content-Disposition names it)"}}


class CompFormat(str, Enum):
    linuxcnc = "linuxcnc"
    beckhoff = "beckhoff"
    csv = "csv"


def _folder_with(base: Path, run_file: str) -> Path | None:
    """The dataset folder that holds ``run_file``: the axis' own, else the newest ``@<time>`` one."""
    candidates = [base] + sorted(base.parent.glob(base.name + "@*"), reverse=True)
    for folder in candidates:
        if not (folder / "dataset.json").is_file():
            continue
        try:
            meta = read_dataset(folder, load_runs=False)
        except DatasetError:
            continue
        on_disk = (folder / run_file).is_file() or (folder / (run_file + ".gz")).is_file()  # .gz: retention
        if on_disk and any(r.spec.file == run_file for r in meta.runs):
            return folder
    return None


@router.get("/axes/{axis_id}/compensation", response_class=Response, responses=TABLE,
            summary="The last measurement as a bidirectional compensation table: LinuxCNC COMP_FILE, "
                    "Beckhoff/ISG lead-screw error list, or CSV")
def compensation(
    axis_id: AxisId, s: SessionDep, svc: ServiceDep, _k: ReadKey,
    format: Annotated[CompFormat, Query(description="table format")] = CompFormat.csv,  # noqa: A002 - the API's name
    comp_type: Annotated[int, Query(ge=0, le=1, description="LinuxCNC COMP_FILE_TYPE (0 or 1)")] = 1,
    step_mm: Annotated[float, Query(ge=0.01, le=1000, description="spacing of the table's points, mm")] = 5.0,
    joint: Annotated[int | None, Query(ge=0, le=255, description="LinuxCNC joint / ISG logical axis")] = None,
    reference_mm: Annotated[float | None, Query(description="where the midline is zero (mm)")] = None,
):
    axis = config_repo.get_axis(s, axis_id)
    result = results_repo.latest_result(s, axis_id)
    if result is None:
        raise NotFoundError("measurement for axis", axis_id)
    cycle, _ = results_repo.get_measurement(s, result.cycle_id, curves=False)
    if not cycle.run_file:
        why = cycle.raw_run_lost or "no raw run was written"
        raise ConflictError(f"measurement {cycle.id} of axis {axis_id} kept no raw run to build a table from ({why})")
    folder = _folder_with(svc.executor.dataset_folder(axis), cycle.run_file) if svc.executor is not None else None
    if folder is None:
        raise ConflictError(f"the raw run {cycle.run_file} of measurement {cycle.id} is no longer in the dataset "
                            f"folder of axis {axis_id} (removed by retention?)")
    spec, run = load_round_trip(folder, cycle.run_file)
    rt = analyse(axis, run.time_s, run.motor_rev(spec.name), run.table_mm(spec.name),
                 uncertainty=inputs_of_spec(run.spec, axis.settings.instruments))
    try:
        ex = export(rt, format.value, step_mm=step_mm, comp_type=comp_type, joint=joint,
                    loop_encoder=str(axis.spec.extra.get("loop_encoder", "motor")), reference_mm=reference_mm,
                    source=f"measurement {cycle.id} ({folder.name}/{cycle.run_file})",
                    stem=f"{axis.machine_name}_{axis.name}_m{cycle.id}", temperature_c=run.spec.temperature_c)
    except LoopOnScaleError as exc:
        raise ConflictError(str(exc)) from exc
    safe = "".join(ch if ch.isalnum() or ch in "-_." else "_" for ch in ex.filename)
    return Response(ex.text, media_type=ex.media_type,
                    headers={"Content-Disposition": f'attachment; filename="{safe}"',
                             "X-Measurement-Id": str(cycle.id)})
