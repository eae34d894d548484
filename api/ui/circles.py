"""The circular tests (ISO 230-4) on the dashboard: the axis page's panel (registered in
api/ui/panels.py) with the axis' latest test, and its polar plot.

The panel shows the figures as stored (storage/db/circles_repo.py: the test's figures, each
axis' agreement of its reversal spikes with Eq. 8 at its b̄, each axis' decision against
its circle tasks); the plot is :func:`api.service.figures.circle_record.render`, the same
figure as the REST API's ``GET /circles/{id}/plot.png``, through the
service's render gate and figure cache.
"""

from __future__ import annotations

import math
from typing import Annotated

from fastapi import APIRouter, Path, Request
from fastapi.responses import Response

from api.service.figures import circle_record
from api.service.figures.gate import RenderBusy
from api.ui import panels
from api.ui.routes import Who, templates
from storage.db import circles_repo, config_repo, session_scope

router = APIRouter(prefix="/ui", include_in_schema=False)
Id = Annotated[int, Path(ge=1, le=2**31 - 1)]  # a database id: anything else is a 422, not an overflow
TEMPLATE = "_axis_circles.html"
VERDICT_WORDS = {"agree": "agree", "larger": "spikes larger than Eq. 8", "smaller": "spikes smaller than Eq. 8"}


def _finite(v) -> float | None:
    return float(v) if isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v) else None


def fixed(v, nd: int = 2, fmt: str = "") -> str:
    """A stored figure to ``nd`` decimals ("–" when it is not a finite number: JSON keeps
    NaN and infinities as null)."""
    x = _finite(v)
    return "–" if x is None else f"{x:{fmt}.{nd}f}"


def pm(value, u, nd: int = 2) -> str:
    """"value ± U µm" of a stored figure and its expanded uncertainty."""
    return f"{fixed(value, nd)} ± {fixed(u, nd)} µm" if _finite(value) is not None else "–"


templates.env.filters.update(fixed=fixed)
templates.env.globals.update(pm=pm)


def panel_context(svc, s, axis_id: int) -> dict:
    axis = config_repo.get_axis(s, axis_id)
    rec = circles_repo.latest_circular_test(s, axis_id)
    ctx = {"test": rec, "axis_name": axis.name, "machine_name": axis.machine_name, "machine_id": axis.machine_id,
           "verdict_words": VERDICT_WORDS}
    if rec is None:  # how to run one, at the radius and feed of the axis' circle tasks (those get judged)
        ctx["circle_tasks"] = [t for t in axis.tasks if t.profile == "circle"]
        return ctx
    f = rec.figures or {}
    spikes = [sp for sp in f.get("spikes", []) if sp.get("axis") == axis.name]
    other = next((a for a in rec.plane if a != axis.name), None)
    ctx.update(
        figures=f, other_axis=other, spikes=spikes,
        count=circles_repo.count_circular_tests(s, rec.machine_id, axis_id),
        agreement=(rec.agreement or {}).get(axis.name),
        decision=(rec.decision or {}).get(axis.name),
        hysteresis_um=_finite(f.get("hysteresis_um")),
        hysteresis_uncertainty_um=_finite(f.get("hysteresis_uncertainty_um")),
        instrument=rec.instrument or {},
        plot_url=f"/ui/axes/{axis_id}/circles/{rec.id}/plot.png",
        api_plot_url=f"/api/v1/circles/{rec.id}/plot.png?axis={axis.name}",
    )
    return ctx


panels.register_axis_panel(panels.AxisPanel(TEMPLATE, panel_context))


@router.get("/axes/{axis_id}/circles/{circle_id}/plot.png")
async def circle_plot(request: Request, axis_id: Id, circle_id: Id, who: Who):
    """The polar plot of circular test ``circle_id``, with this axis' tolerance band; a test
    whose plane does not hold the axis is not found."""
    svc = request.app.state.service

    def render() -> bytes:  # through the service's render gate, as every figure (limits.plot_*)
        with session_scope(svc.factory) as s:
            axis = config_repo.get_axis(s, axis_id)  # the test must be of its machine, with it in its plane
            return circle_record.render(s, circle_id, machine_id=axis.machine_id, axis=axis.name,
                                        draw=svc.plots.draw, cache=svc.figures)

    try:
        png = await svc.render_gate.run(render)
    except RenderBusy as exc:
        wait_s = max(1, round(exc.retry_after_s))
        return Response(str(exc), status_code=429, media_type="text/plain", headers={"Retry-After": str(wait_s)})
    return Response(png, media_type="image/png", headers={"Cache-Control": "no-cache"})
