"""Sections that other features add to the axis page (work orders, repairs, ...).

A feature registers an :class:`AxisPanel`: a template (a file under
``api/ui/templates``, named ``_axis_<feature>.html`` by convention) and a function giving
its variables from the service, an open database session and the axis id. The axis
page renders every registered panel, in order of registration, between the history and
the last cycles, with the panel's variables under ``panel`` and the page's own (``axis``,
``who``: roles and CSRF token for its forms) beside them. Forms of a panel post to the
feature's own routes (with ``who.csrf``, and ``Posted``/``who.require`` from
``api.ui.routes``).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from sqlalchemy.orm import Session


@dataclass(frozen=True)
class AxisPanel:
    template: str
    context: Callable[[Any, Session, int], dict]  # (service, db session, axis id) -> the template's ``panel``


AXIS_PANELS: list[AxisPanel] = []


def register_axis_panel(panel: AxisPanel) -> AxisPanel:
    if all(p.template != panel.template for p in AXIS_PANELS):
        AXIS_PANELS.append(panel)
    return panel


def render_context(svc, s: Session, axis_id: int) -> list[tuple[str, dict]]:
    return [(p.template, p.context(svc, s, axis_id)) for p in AXIS_PANELS]
