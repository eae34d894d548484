"""The polar plot of a stored circular test: its inputs from the record
(:func:`storage.db.circles_repo.get_circular_test`), its cache key, the render.

The REST plot (``GET /circles/{id}/plot.png``) and the axis page's panel both
call :func:`render`, so both draw the same figure from the same reading of the record. The
drawing itself is :func:`api.service.figures.circle.polar`, run through the service's plot
process as every figure; a stored test never changes, so its figure is keyed by its id (and
the axis whose tolerance band it shows) and drawn once.
"""

from __future__ import annotations

import math
from collections.abc import Callable

from api.service.figures import circle
from api.service.figures.cache import FigureCache
from core.circle import analyze
from storage.db import NotFoundError, circles_repo


def _here(fn: Callable[..., bytes], *args, **kwargs) -> bytes:
    return fn(*args, **kwargs)


def _num(v) -> float | None:
    return float(v) if isinstance(v, (int, float)) and math.isfinite(v) else None


def _f(v, nd: int = 1, sign: str = "") -> str:
    x = _num(v)
    return "–" if x is None else f"{x:{sign}.{nd}f}"


def agreement_line(a: dict) -> str:
    """One axis' spikes against Eq. 8, as the plot's side writes it (JSON keeps NaN and
    infinities as null: those are "–")."""
    return (f"spikes {_f(a.get('measured_um'))} ± {_f(a.get('measured_uncertainty_um'))} µm, Eq. 8 at b̄ "
            f"{_f(a.get('backlash_um'))} µm {_f(a.get('predicted_um'))} ± {_f(a.get('predicted_uncertainty_um'))} µm: "
            f"{a.get('verdict', '–')} (E_n {_f(a.get('normalised_error'), 2, '+')})")


def decision_line(d: dict) -> str:
    return (f"{d.get('state')} on task {d.get('task')}: TBE {_f(d.get('error_um'))} ± {_f(d.get('uncertainty_um'))} µm "
            f"against {_f(d.get('tolerance_um'), 3).rstrip('0').rstrip('.')} µm ({d.get('rule', '')} rule)")


def band_decision(rec, axis: str | None) -> tuple[str, dict] | None:
    """(axis, decision) whose task's tolerance band the plot draws: ``axis``' when it was
    judged; without ``axis``, the judged task with the smallest tolerance (the strictest band)."""
    judged = {a: d for a, d in (rec.decision or {}).items() if d and _num(d.get("tolerance_um"))}
    if axis is not None:
        return (axis, judged[axis]) if axis in judged else None
    if not judged:
        return None
    return min(judged.items(), key=lambda kv: kv[1]["tolerance_um"])


def figures_of(rec) -> dict:
    """The stored figures; a test stored without them is analysed here (same function)."""
    return rec.figures if rec.figures else analyze(rec.test).to_dict()


def title_of(rec) -> str:
    t = f", {rec.temperature_c:.1f} °C" if rec.temperature_c is not None else ""
    return (f"{rec.machine_name} {rec.plane[0]}/{rec.plane[1]} circular test {rec.id}, "
            f"{rec.measured_at:%Y-%m-%d %H:%M} UTC{t}")


def plot_inputs(rec, axis: str | None = None) -> dict:
    """The keyword arguments of :func:`api.service.figures.circle.polar` for the stored test
    ``rec`` (read with its samples), the tolerance band of ``axis``' judged task (see
    :func:`band_decision`)."""
    f = figures_of(rec)
    agreement = rec.agreement or {}
    marks = []
    for sp in f.get("spikes", []):
        a = agreement.get(sp["axis"]) or {}
        marks.append(circle.SpikeMark(
            axis=sp["axis"], quadrant_deg=float(sp["quadrant_deg"]), direction=sp["direction"],
            height_um=float(sp["height_um"]), height_uncertainty_um=float(sp["height_uncertainty_um"]),
            width_deg=_num(sp.get("width_deg")) or 0.0, peak_deg=_num(sp.get("peak_deg")),
            predicted_um=_num(a.get("predicted_um")), predicted_uncertainty_um=_num(a.get("predicted_uncertainty_um"))))
    chosen = band_decision(rec, axis)
    band = None
    if chosen is not None:
        name, d = chosen
        band = circle.Band(task=f"{d['task']} (axis {name})", tolerance_um=float(d["tolerance_um"]),
                           warning_um=_num(d.get("warning_um")))
    summary = circle.Summary(
        circular_deviation_um=f["circular_deviation_um"], circular_deviation_mz_um=f["circular_deviation_mz_um"],
        circular_deviation_uncertainty_um=f["circular_deviation_uncertainty_um"],
        hysteresis_um=_num(f.get("hysteresis_um")), hysteresis_uncertainty_um=_num(f.get("hysteresis_uncertainty_um")),
        agreements={a: agreement_line(v) for a, v in agreement.items() if v},
        decisions=tuple(f"{a}: {decision_line(d)}" for a, d in (rec.decision or {}).items() if d))
    return dict(
        passes={p.direction: (p.angle_deg, p.radial_um) for p in rec.test.passes},
        radius_mm=rec.radius_mm, feed_mm_min=rec.feed_mm_min, plane=tuple(rec.plane),
        centre_offset_um=tuple(f["centre_offset_um"]), mean_radius_deviation_um=f["mean_radius_deviation_um"],
        spikes=marks, summary=summary, band=band, title=title_of(rec),
        spike_window_deg=_num(f.get("spike_window_deg")))


def render(s, circle_id: int, *, machine_id: int | None = None, axis: str | None = None,
           draw: Callable[..., bytes] | None = None, cache: FigureCache | None = None) -> bytes:
    """The PNG of circular test ``circle_id`` (of machine ``machine_id`` when given: another
    machine's test is not found), with ``axis``' tolerance band. Raises NotFoundError for an
    unknown test, machine or an axis not in its plane."""
    draw = draw or _here
    rec = circles_repo.get_circular_test(s, circle_id)
    if machine_id is not None and rec.machine_id != machine_id:
        raise NotFoundError(f"circular test of machine {machine_id}", circle_id)
    if axis is not None and axis not in rec.plane:
        raise NotFoundError(f"axis of circular test {circle_id} (its plane is {rec.plane[0]}/{rec.plane[1]})", axis)

    def drawn() -> bytes:
        return draw(circle.polar, **plot_inputs(rec, axis))

    if cache is None:
        return drawn()
    # a stored test never changes: its id, the band's axis and the title name every input
    return cache.get_or_render(("circle", rec.id, axis, title_of(rec)), drawn)
