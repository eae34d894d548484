"""Fault injection for the simulated controllers.

A fault is written ``KIND[:key=value,...]`` on the command line (``--fault``) and in
tests. Keys: ``at`` (fraction of the round trip's duration, 0..1, default 0.5),
``for`` (seconds of wall clock the fault lasts, default: until the cycle ends),
``cycles`` (how many round trips it affects, default 1: the next one is clean),
and kind-specific values:

====================  =============================================================
``stuck``             table encoder value freezes at ``at``
``jump``              table encoder value jumps by ``mm`` (default 0.5) at ``at``
``glitch``            one table encoder sample is off by ``mm`` (default 5) at
                      ``at``; ``n`` such samples (default 1), 1 % of the trace apart
``lost``              ``n`` (default 5) samples are not latched/sent at ``at``
``emcy``              drive/controller fault with ``code`` (default 0x7305) at ``at``
``drop``              connection dropped at ``at``; new connections refused ``for`` s
                      (CANopen: the drive falls silent, heartbeat included)
``slow``              replies delayed by ``s`` seconds (default 2) from ``at`` on
``exception``         Modbus exception ``code`` (default 4, device failure) from ``at``
``refuse``            Modbus: no connection accepted ``for`` s from start-up
``duplicate``         CANopen: the next ``n`` (default 3) TPDOs are sent twice from ``at``
``reorder``           CANopen: ``n`` (default 3) TPDOs from ``at`` each go out after the next one
====================  =============================================================
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

from core.errors import InputError

KINDS = ("stuck", "jump", "glitch", "lost", "emcy", "drop", "slow", "exception", "refuse", "duplicate", "reorder")
_DEFAULTS = {"jump": {"mm": 0.5}, "glitch": {"mm": 5.0, "n": 1}, "lost": {"n": 5}, "emcy": {"code": 0x7305},
             "slow": {"s": 2.0}, "exception": {"code": 4}, "duplicate": {"n": 3}, "reorder": {"n": 3}}


@dataclass(frozen=True)
class Fault:
    """One injected fault. ``params`` holds the kind-specific values (mm, n, code, s)."""

    kind: str
    at: float = 0.5
    for_s: float = math.inf
    cycles: int = 1
    params: dict = field(default_factory=dict)

    def __post_init__(self) -> None:
        if self.kind not in KINDS:
            raise InputError(f"fault kind (={self.kind!r}) must be one of {KINDS}")
        if not 0.0 <= self.at <= 1.0:
            raise InputError(f"fault {self.kind}: at (={self.at}) must be a fraction in [0, 1]")
        if not self.for_s > 0:
            raise InputError(f"fault {self.kind}: for (={self.for_s}) must be > 0 s")
        if self.cycles < 1:
            raise InputError(f"fault {self.kind}: cycles (={self.cycles}) must be >= 1")

    def value(self, key: str):
        return self.params.get(key, _DEFAULTS.get(self.kind, {}).get(key))


def parse_fault(text: str) -> Fault:
    """Parse ``KIND[:key=value,...]`` (see the module docstring)."""
    kind, _, rest = text.strip().partition(":")
    kw: dict = {}
    params: dict = {}
    for item in filter(None, (s.strip() for s in rest.split(","))):
        key, eq, raw = item.partition("=")
        if not eq:
            raise InputError(f"fault {text!r}: {item!r} must be key=value")
        try:
            val = float(int(raw, 0)) if raw.lower().startswith("0x") else float(raw)
        except ValueError as exc:
            raise InputError(f"fault {text!r}: {key} (={raw!r}) must be a number") from exc
        if key == "at":
            kw["at"] = val
        elif key == "for":
            kw["for_s"] = val
        elif key == "cycles":
            kw["cycles"] = int(val)
        elif key in ("mm", "n", "code", "s"):
            params[key] = int(val) if key in ("n", "code") else val
        else:
            raise InputError(f"fault {text!r}: unknown key {key!r} (at, for, cycles, mm, n, code, s)")
    return Fault(kind=kind.strip().lower(), params=params, **kw)


class FaultSchedule:
    """The faults of a simulated controller and which cycles they still affect."""

    def __init__(self, faults=()):
        self._left = {i: f.cycles for i, f in enumerate(faults)}
        self._faults = list(faults)
        self.active: list[Fault] = []

    def add(self, fault: Fault) -> None:
        self._left[len(self._faults)] = fault.cycles
        self._faults.append(fault)

    def begin_cycle(self) -> list[Fault]:
        """Faults for the round trip being started (each consumes one of its cycles)."""
        self.active = []
        for i, f in enumerate(self._faults):
            if f.kind == "refuse":
                continue
            if self._left[i] > 0:
                self._left[i] -= 1
                self.active.append(f)
        return self.active

    def has(self, kind: str) -> bool:
        """A fault of ``kind`` is configured (whether or not it has cycles left)."""
        return any(f.kind == kind for f in self._faults)

    def startup(self, kind: str) -> Fault | None:
        for f in self._faults:
            if f.kind == kind:
                return f
        return None

    def clear(self) -> None:
        self._left = {i: 0 for i in self._left}
        self.active = []
