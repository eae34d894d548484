"""How a machine's or an axis' name appears on the interfaces, and which names collide there.

A name is free text in the database, but an MQTT topic level cannot hold ``/ + #`` and
a subscriber cannot tell blanks from ``_`` apart: each run of those characters becomes
one ``_`` (and the ends are trimmed), so ``"m a"``, ``"m_a"`` and ``"m/a"`` all publish
under ``.../m_a/...`` and would use the same MQTT client id. Two machines (or two axes
of one machine) whose names map to one interface name are therefore refused when the
second is created (:func:`collision`), by the REST API, the dashboard and the
configuration file alike. MTConnect ids, OPC UA node ids and dataset folder names come
from the numeric ids or from the exact name, so they never collide for distinct names.
"""

from __future__ import annotations

import re
from collections.abc import Iterable

_NOT_IN_A_TOPIC_LEVEL = re.compile(r"[/+#\s]+")


def interface_name(name: str) -> str:
    """``name`` as one MQTT topic level (and the machine's part of a client id)."""
    return _NOT_IN_A_TOPIC_LEVEL.sub("_", name).strip("_") or "_"


def collision(name: str, others: Iterable[str]) -> str | None:
    """The first of ``others`` (not ``name`` itself) whose interface name is ``name``'s, or None."""
    mine = interface_name(name)
    return next((o for o in others if o != name and interface_name(o) == mine), None)


def collision_message(what: str, name: str, other: str) -> str:
    """Why ``name`` is refused: it would share the topics of ``other``."""
    return (f"{what} name {name!r} maps to the MQTT topic level {interface_name(name)!r}, as the {what} {other!r} "
            f"does already: the two would publish under one topic and one client id. Choose a name that differs "
            f"from {other!r} in more than blanks and the characters / + #")
