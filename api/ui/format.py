"""Number and time formatting for the templates: units on every figure."""

from __future__ import annotations

import math
from datetime import datetime

from core.tbe import stored_repair_target


def um(v: float | None, nd: int = 1) -> str:
    if v is None or not math.isfinite(v):
        return "–"
    return f"{v:.{nd}f} µm"


def pct(v: float | None) -> str:
    return "–" if v is None else f"{100 * v:.0f} %"


def age(s: float | None) -> str:
    if s is None:
        return "never"
    s = max(s, 0.0)
    if s < 90:
        return f"{s:.0f} s ago"
    if s < 90 * 60:
        return f"{s / 60:.0f} min ago"
    if s < 36 * 3600:
        return f"{s / 3600:.1f} h ago"
    return f"{s / 86400:.1f} d ago"


def duration(s: float | None) -> str:
    """Seconds as a person says them: "40 s", "3 min"."""
    if s is None:
        return "–"
    s = max(s, 0.0)
    if s < 90:
        return f"{s:.0f} s"
    return f"{s / 60:.0f} min"


def when(t: datetime | None) -> str:
    return "–" if t is None else t.strftime("%Y-%m-%d %H:%M UTC")


def restore_below_explanation(order) -> str:
    """Why a work order's repair target is below the backlash limit ("" when it names none)."""
    target = stored_repair_target(order.restore_below_um, order.backlash_limit_um)
    return target.explanation if target is not None else ""


def recommendation_without_restore(order) -> str:
    """A work order's recommendation without its closing "Restore the backlash below ..."
    sentence when the panel shows that target on its own line, so it reads once."""
    rec = order.recommendation or ""
    if order.restore_below_um is None:
        return rec
    cut = rec.find(" Restore the backlash below ")
    return rec[:cut] if cut >= 0 else rec


def state_class(state: str | None) -> str:
    return {"OK": "ok", "WARNING": "warn", "ALARM": "alarm"}.get(state or "", "unknown")


def due(t: datetime | None, now: datetime) -> str:
    """A scheduled time as "in 12 min" (the absolute time goes in a tooltip)."""
    if t is None:
        return "not scheduled"
    s = (t - now).total_seconds()
    if s <= 0:
        return "due now"
    return "in " + age(s).removesuffix(" ago")
