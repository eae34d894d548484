"""The service's one internal event source, fanned out to every interface.

The cycle executor calls the service when a cycle is saved; the service turns that into
:class:`Event` objects (``measurement_stored``, ``cycle_failed``, ``alert_changed``, ``work_order_changed``) and
:meth:`EventHub.publish` hands each to every subscriber's own bounded queue, without
waiting: a slow or dead consumer never delays a cycle or another consumer. Each
subscriber runs its handler on its own thread; a full queue drops its oldest event and
counts it (``dropped``), and a handler that raises is logged and counted (``failed``),
never propagated.
"""

from __future__ import annotations

import collections
import logging
import threading
from collections.abc import Callable
from dataclasses import dataclass
from datetime import datetime

from core.tbe import stored_repair_target
from storage.db import AlertRecord, CycleRecord, WorkOrderRecord, utcnow

log = logging.getLogger("mebm.events")

# axis_changed: created or reconfigured; work_order_changed: a maintenance order opened or moved;
# circular_test_stored: a circular test of the axis' plane was stored (its status shows the figures)
KINDS = ("measurement_stored", "cycle_failed", "alert_changed", "axis_changed", "work_order_changed",
         "circular_test_stored")


@dataclass(frozen=True)
class Event:
    kind: str
    axis_id: int
    machine: str
    axis: str
    at: datetime
    cycle: CycleRecord | None = None
    alert: AlertRecord | None = None
    order: WorkOrderRecord | None = None  # work_order_changed: the order after the step (transitions[-1] is it)


class Subscription:
    """One consumer: a bounded queue and the thread that empties it into ``handler``."""

    def __init__(self, name: str, handler: Callable[[Event], None], maxsize: int):
        self.name = name
        self.handler = handler
        self.maxsize = maxsize
        self.delivered = self.dropped = self.failed = 0
        self._queue: collections.deque[Event] = collections.deque()
        self._cond = threading.Condition()
        self._closed = False
        self._thread = threading.Thread(target=self._run, name=f"mebm-events-{name}", daemon=True)
        self._thread.start()

    def offer(self, ev: Event) -> None:
        with self._cond:
            if self._closed:
                return
            if len(self._queue) >= self.maxsize:
                self._queue.popleft()
                self.dropped += 1
                if self.dropped in (1, 10, 100) or self.dropped % 1000 == 0:
                    log.warning("event consumer %s is behind: %d event(s) dropped", self.name, self.dropped)
            self._queue.append(ev)
            self._cond.notify()

    def _run(self) -> None:
        while True:
            with self._cond:
                while not self._queue and not self._closed:
                    self._cond.wait()
                if self._closed and not self._queue:
                    return
                ev = self._queue.popleft()
            try:
                self.handler(ev)
                self.delivered += 1
            except Exception:  # noqa: BLE001 - a consumer's fault stays in the consumer
                self.failed += 1
                log.exception("event consumer %s failed on %s of axis %s", self.name, ev.kind, ev.axis_id)

    def close(self, timeout_s: float = 5.0) -> None:
        with self._cond:
            self._closed = True
            self._cond.notify()
        self._thread.join(timeout_s)

    @property
    def pending(self) -> int:
        return len(self._queue)


class EventHub:
    def __init__(self) -> None:
        self._subs: list[Subscription] = []
        self._lock = threading.Lock()

    def subscribe(self, name: str, handler: Callable[[Event], None], maxsize: int = 1000) -> Subscription:
        sub = Subscription(name, handler, maxsize)
        with self._lock:
            self._subs.append(sub)
        return sub

    def unsubscribe(self, sub: Subscription) -> None:
        with self._lock:
            if sub in self._subs:
                self._subs.remove(sub)
        sub.close()

    def publish(self, ev: Event) -> None:
        with self._lock:
            subs = list(self._subs)
        for s in subs:
            s.offer(ev)

    def close(self) -> None:
        with self._lock:
            subs, self._subs = self._subs, []
        for s in subs:
            s.close()

    @property
    def subscriptions(self) -> tuple[Subscription, ...]:
        with self._lock:
            return tuple(self._subs)


def events_of_saved_cycle(axis_id: int, machine: str, axis: str, cycle: CycleRecord,
                          alerts: list[AlertRecord]) -> list[Event]:  # fmt: skip
    """The events of one saved cycle: stored or failed, then each alert change."""
    now = utcnow()
    out = []
    if cycle.status == "ok":
        out.append(Event("measurement_stored", axis_id, machine, axis, now, cycle=cycle))
    elif cycle.status == "failed":
        out.append(Event("cycle_failed", axis_id, machine, axis, now, cycle=cycle))
    out += [Event("alert_changed", axis_id, machine, axis, now, cycle=cycle, alert=a) for a in alerts]
    return out


def _explanation(o) -> str | None:
    target = stored_repair_target(o.restore_below_um, o.backlash_limit_um)
    return target.explanation if target is not None else None


def order_document(ev: Event) -> dict:
    """A work-order step as the MQTT and webhook outputs carry it."""
    o = ev.order
    last = o.transitions[-1] if o.transitions else None
    return {
        "machine": ev.machine, "axis": ev.axis, "axis_id": ev.axis_id, "order_id": o.id, "kind": o.kind,
        "state": o.state, "from": last.from_state if last else None, "at": last.at.isoformat() if last else None,
        "by": last.by if last else None, "note": last.note if last else "", "binding_task": o.binding_task,
        "tolerance_um": o.tolerance_um, "backlash_um": o.backlash_um, "tbe_um": o.tbe_um,
        "restore_below_um": o.restore_below_um, "restore_below_explanation": _explanation(o),
        "due_at": o.due_at.isoformat() if o.due_at else None,
        "recommendation": o.recommendation, "opened_by_circular_test_id": o.opened_by_circular_test_id,
        "verification": {k: o.verification.get(k) for k in ("passed", "against", "message")} if o.verification else None,
    }  # fmt: skip
