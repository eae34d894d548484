"""/axes/{id}/plots/{name}.png: the figures a maintenance worker reads (Figs. 5, 9, 10, 14, 15);
/circles/{id}/plot.png: a circular test's polar plot (ISO 230-4), beside the test's JSON at /circles/{id}.

A figure is drawn once per set of inputs (the stored results it shows and its parameters)
and then served from the service's figure cache, which the dashboard shares: repeated or
concurrent requests for one figure do not hold the worker threads with renders.

Renders go through the service's :class:`~api.service.figures.gate.RenderGate`: at most
``limits.plot_renders`` drawn at once and ``limits.plot_queue`` waiting (on the event loop,
without a thread or a database connection); beyond that 429 with ``Retry-After``. ``since``
is rounded down to ``limits.plot_window_step_s``, the figure cache's resolution."""

from __future__ import annotations

from enum import Enum
from typing import Annotated

from fastapi import APIRouter, Path, Query, Response

from api.rest.auth import ReadKey
from api.rest.deps import AxisId, ServiceDep
from api.rest.errors import TooManyRequestsError
from api.rest.routers.axes import Since, utc
from api.service.figures import axis as axis_figures
from api.service.figures import circle_record
from api.service.figures.gate import RenderBusy
from storage.db import session_scope

router = APIRouter(tags=["plots"])
PNG = {200: {"content": {"image/png": {}}, "description": "a PNG image"},
       429: {"description": "limits.plot_renders figures are being drawn and limits.plot_queue wait: ask again "
                            "after Retry-After seconds"}}


class PlotName(str, Enum):
    backlash_profile = "backlash_profile"
    lead_deviation = "lead_deviation"
    tbe_vs_backlash = "tbe_vs_backlash"
    tbe_history = "tbe_history"
    backlash_trend = "backlash_trend"
    prognosis = "prognosis"


@router.get("/axes/{axis_id}/plots/{name}.png", response_class=Response, responses=PNG,
            summary="A figure: backlash_profile (Fig. 9), lead_deviation (Fig. 5), tbe_vs_backlash (Fig. 14), "
                    "tbe_history (Fig. 15), backlash_trend (Fig. 10), prognosis (Fig. 10 with the forecast and its band); "
                    "since is rounded down to limits.plot_window_step_s (default the hour)")
async def plot(
    axis_id: AxisId, name: PlotName, svc: ServiceDep, _k: ReadKey,
    measurement_id: Annotated[int | None, Query(ge=1, le=2**31 - 1,
                                                description="for profile/lead plots; default the newest")] = None,
    direction: Annotated[str, Query(pattern="^(positive|negative)$", description="lead_deviation stroke")] = "positive",
    since: Since = None,
):
    def render() -> bytes:  # on a thread of the render gate, with a database session of its own
        with session_scope(svc.factory) as s:
            return axis_figures.render(
                s, axis_id, name.value, measurement_id=measurement_id, direction=direction, since=utc(since),
                status=svc.status.get(axis_id) if name is PlotName.prognosis else None,
                draw=svc.plots.draw, cache=svc.figures)

    try:
        png = await svc.render_gate.run(render)
    except RenderBusy as exc:
        raise TooManyRequestsError(str(exc), exc.retry_after_s) from None
    return Response(content=png, media_type="image/png", headers={"Cache-Control": "no-cache"})


CircleId = Annotated[int, Path(ge=1, le=2**31 - 1, description="circular test id")]


@router.get("/circles/{circle_id}/plot.png", response_class=Response, responses=PNG,
            summary="A circular test's polar plot (ISO 230-4): both directions about the least-squares circle, "
                    "magnified; the tolerance band of the circle task it was judged against; each reversal spike "
                    "with its measured height and Eq. 8's prediction at the axis' b̄; G, H and the verdicts")
async def circle_plot(
    circle_id: CircleId, svc: ServiceDep, _k: ReadKey,
    axis: Annotated[str | None, Query(max_length=50, description="the axis whose task's tolerance band is drawn; "
                                                                 "default the strictest judged task")] = None,
):
    def render() -> bytes:
        with session_scope(svc.factory) as s:
            return circle_record.render(s, circle_id, axis=axis, draw=svc.plots.draw,
                                        cache=svc.figures)

    try:
        png = await svc.render_gate.run(render)
    except RenderBusy as exc:
        raise TooManyRequestsError(str(exc), exc.retry_after_s) from None
    return Response(content=png, media_type="image/png", headers={"Cache-Control": "no-cache"})
