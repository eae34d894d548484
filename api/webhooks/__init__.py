"""Webhooks: alert changes POSTed to configured URLs, signed per Standard Webhooks
(https://www.standardwebhooks.com, issue 17), for MES systems that only take HTTP.

Each delivery is a JSON body ``{"type": "alert.raised" | "alert.cleared" | "work_order.<state>", "timestamp",
"data": {...}}`` with the headers ``webhook-id`` (``msg_<uuid>``, the same on every
retry), ``webhook-timestamp`` (Unix seconds) and ``webhook-signature``
(``v1,<base64 HMAC-SHA256>`` of ``"{id}.{timestamp}.{body}"`` with the secret's key: the
base64 after ``whsec_``). A 2xx answer ends it; anything else (an error status, a
refused connection, a time-out) is retried with back-off (1, 2, 4, ... s, at most
``max_attempts`` tries). Every attempt is kept in a bounded delivery log (``deliveries``,
served at ``GET /api/v1/webhooks/deliveries`` for an admin key). Sending runs on the
event hub's own consumer thread: a slow receiver never delays a cycle or another
interface. The standard library's HTTP client is used: the service has no other.
"""

from __future__ import annotations

import base64
import collections
import hashlib
import hmac
import json
import logging
import threading
import time
import urllib.error
import urllib.request
import uuid
from collections.abc import Callable
from dataclasses import asdict, dataclass
from datetime import datetime, timezone

from api.service.config import WebhookSettings
from api.service.events import Event, order_document

log = logging.getLogger("mebm.webhooks")


def sign(secret: str, msg_id: str, timestamp: int, body: bytes) -> str:
    """The ``webhook-signature`` value for ``body`` (Standard Webhooks, v1)."""
    key = base64.b64decode(secret.removeprefix("whsec_"))
    mac = hmac.new(key, f"{msg_id}.{timestamp}.".encode() + body, hashlib.sha256).digest()
    return "v1," + base64.b64encode(mac).decode()


@dataclass(frozen=True)
class Delivery:
    msg_id: str
    url: str
    event_type: str
    axis_id: int
    attempt: int
    at: str
    status: int | None  # HTTP status, None when no answer
    error: str | None
    delivered: bool


class WebhookSender:
    def __init__(self, service, settings: WebhookSettings, *, sleep: Callable[[float], None] = time.sleep):
        self.settings = settings
        self.sleep = sleep
        self.deliveries: collections.deque[Delivery] = collections.deque(maxlen=settings.log_max)
        self.delivered = self.failed = 0
        self._lock = threading.Lock()
        self.service = service
        self.subscription = service.events.subscribe("webhooks", self.handle)

    def handle(self, ev: Event) -> None:
        if ev.kind == "work_order_changed":
            self._order(ev)
            return
        if ev.kind != "alert_changed":
            return
        a = ev.alert
        doc = {
            "type": "alert.raised" if a.active else "alert.cleared",
            "timestamp": ev.at.astimezone(timezone.utc).isoformat().replace("+00:00", "Z"),
            "data": {"machine": ev.machine, "axis": ev.axis, "axis_id": ev.axis_id, "alert_id": a.id, "kind": a.kind,
                     "active": a.active, "task_name": a.task_name, "tbe_um": a.tbe_um, "tolerance_um": a.tolerance_um,
                     "backlash_um": a.backlash_um, "backlash_limit_um": a.backlash_limit_um, "message": a.message},
        }  # fmt: skip
        body = json.dumps(doc, separators=(",", ":")).encode()
        msg_id = f"msg_{uuid.uuid4().hex}"
        for url in self.settings.urls:
            self._deliver(url, msg_id, doc["type"], ev.axis_id, body)

    def _order(self, ev: Event) -> None:
        """A work-order step (issue 20): ``work_order.<state>``, e.g. ``work_order.verified``."""
        doc = {"type": f"work_order.{ev.order.state}",
               "timestamp": ev.at.astimezone(timezone.utc).isoformat().replace("+00:00", "Z"),
               "data": order_document(ev)}
        body = json.dumps(doc, separators=(",", ":")).encode()
        msg_id = f"msg_{uuid.uuid4().hex}"
        for url in self.settings.urls:
            self._deliver(url, msg_id, doc["type"], ev.axis_id, body)

    def _deliver(self, url: str, msg_id: str, event_type: str, axis_id: int, body: bytes) -> None:
        for attempt in range(1, self.settings.max_attempts + 1):
            ts = int(time.time())
            req = urllib.request.Request(url, data=body, method="POST", headers={
                "content-type": "application/json", "user-agent": "mebm-webhooks/1", "webhook-id": msg_id,
                "webhook-timestamp": str(ts), "webhook-signature": sign(self.settings.secret, msg_id, ts, body)})  # fmt: skip
            status = error = None
            try:
                with urllib.request.urlopen(req, timeout=self.settings.timeout_s) as resp:  # noqa: S310 - configured URLs
                    status = resp.status
            except urllib.error.HTTPError as exc:
                status, error = exc.code, f"HTTP {exc.code}"
            except (urllib.error.URLError, OSError, TimeoutError) as exc:
                error = str(getattr(exc, "reason", exc))
            ok = status is not None and 200 <= status < 300
            self._log(Delivery(msg_id, url, event_type, axis_id, attempt,
                               datetime.now(timezone.utc).isoformat(), status, error, ok))  # fmt: skip
            if ok:
                return
            if attempt < self.settings.max_attempts:
                self.sleep(min(2.0 ** (attempt - 1), 60.0))
        log.warning("webhook %s to %s not delivered after %d attempts", msg_id, url, self.settings.max_attempts)

    def _log(self, d: Delivery) -> None:
        with self._lock:
            self.deliveries.append(d)
            if d.delivered:
                self.delivered += 1
            else:
                self.failed += 1

    def log_entries(self) -> list[dict]:
        with self._lock:
            return [asdict(d) for d in reversed(self.deliveries)]

    def close(self) -> None:
        self.service.events.unsubscribe(self.subscription)
