"""Webhooks: alert changes POSTed to configured URLs, signed per Standard Webhooks
(https://www.standardwebhooks.com), for MES systems that only take HTTP.

Each delivery is a JSON body ``{"type": "alert.raised" | "alert.cleared" | "work_order.<state>", "timestamp",
"data": {...}}`` (``data`` names the installation, ``instance``, as every MQTT payload
does) with the headers ``webhook-id`` (``msg_<uuid>``, the same on every
retry), ``webhook-timestamp`` (Unix seconds) and ``webhook-signature``
(``v1,<base64 HMAC-SHA256>`` of ``"{id}.{timestamp}.{body}"`` with the secret's key: the
base64 after ``whsec_``).

Nothing is lost: the event hub's consumer only stores each message, one row per receiver
URL (:mod:`storage.db.webhooks_repo`), and a sender thread posts the due rows. A 2xx
answer ends a message; anything else (an error status, a refused connection, a time-out)
is retried with back-off (1, 2, 4, ... s, at most 60 s, ``max_attempts`` tries), holding
the receiver's later messages back (each receiver gets its messages in order), then the
message is ``failed``: kept, listed at ``GET /api/v1/webhooks/messages?state=failed`` and
sent again after ``POST /api/v1/webhooks/messages/retry`` (admin). A stop or a crash
leaves pending rows for the next start, or for another live worker on the same database
once the dead sender's claim has run out: delivery is at least once, and a receiver drops
a repeat by its ``webhook-id``. While the database is unreachable, messages wait in memory
(bounded, counted when dropped) until it answers. Every attempt is also kept in a bounded
in-memory log (``GET /api/v1/webhooks/deliveries``). A slow receiver never delays a cycle
or another interface. The standard library's HTTP client is used: the service has no other.
"""

from __future__ import annotations

import base64
import collections
import contextlib
import hashlib
import hmac
import json
import logging
import threading
import time
import urllib.error
import urllib.request
import uuid
from dataclasses import asdict, dataclass
from datetime import datetime, timedelta, timezone

from api.service.config.settings import WebhookSettings
from api.service.events import Event, order_document
from storage.db import StorageError, session_scope, webhooks_repo
from storage.db.webhooks_repo import NewMessage

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


POLL_S = 5.0  # a sender looks for due messages (other workers', retries) at least this often
BATCH = 20  # messages claimed at a time
PURGE_EVERY_S = 600.0
UNSTORED_MAX = 10000  # messages held in memory while the database is unreachable


def backoff_s(attempt: int) -> float:
    """The wait after failed attempt ``attempt`` (1-based): 1, 2, 4, ... s, at most 60 s."""
    return min(2.0 ** (attempt - 1), 60.0)


class WebhookSender:
    def __init__(self, service, settings: WebhookSettings):
        self.settings = settings
        self.deliveries: collections.deque[Delivery] = collections.deque(maxlen=settings.log_max)
        self.delivered = self.failed = 0  # attempts, since this start
        self.given_up = 0  # messages that used every attempt (now ``failed`` in the database)
        self.purged_failed = 0  # failed messages deleted beyond ``max_failed``
        self.unstored_dropped = 0  # messages lost while the database was unreachable and memory full
        self.sender = f"webhooks-{uuid.uuid4()}"
        self._unstored: collections.deque[NewMessage] = collections.deque()
        self._lock = threading.Lock()
        self._store_lock = threading.Lock()
        self._wake, self._stop = threading.Event(), threading.Event()
        self._last_purge = 0.0
        self.service = service
        self.subscription = service.events.subscribe("webhooks", self.handle)
        self._thread = threading.Thread(target=self._run, name="mebm-webhooks", daemon=True)
        self._thread.start()

    # -- the event hub's consumer: store, never send --------------------------------------
    def handle(self, ev: Event) -> None:
        if ev.kind == "work_order_changed":
            doc = {"type": f"work_order.{ev.order.state}",  # a work-order step
                   "timestamp": _iso(ev.at), "data": {"instance": self.service.instance, **order_document(ev)}}
        elif ev.kind == "alert_changed":
            a = ev.alert
            doc = {
                "type": "alert.raised" if a.active else "alert.cleared",
                "timestamp": _iso(ev.at),
                "data": {"instance": self.service.instance, "machine": ev.machine, "axis": ev.axis,
                         "axis_id": ev.axis_id, "alert_id": a.id, "kind": a.kind, "active": a.active,
                         "task_name": a.task_name, "tbe_um": a.tbe_um, "tolerance_um": a.tolerance_um,
                         "backlash_um": a.backlash_um, "backlash_limit_um": a.backlash_limit_um, "message": a.message,
                         "raised_by_circular_test_id": a.raised_by_circular_test_id},
            }  # fmt: skip
        else:
            return
        body = json.dumps(doc, separators=(",", ":"))
        msg_id, now = f"msg_{uuid.uuid4().hex}", datetime.now(timezone.utc)
        with self._lock:
            self._unstored.extend(NewMessage(msg_id, url, doc["type"], ev.axis_id, body, now)
                                  for url in self.settings.urls)
            while len(self._unstored) > UNSTORED_MAX:
                self._unstored.popleft()
                self.unstored_dropped += 1
                log.error("webhook message dropped: the database has been unreachable for %d messages", UNSTORED_MAX)
        self._store()
        self._wake.set()

    def _store(self) -> bool:
        """Move the messages held in memory to the database; False while it is unreachable.
        Called by the hub's consumer and the sender thread: one at a time, or both would
        store the same batch."""
        factory = getattr(self.service, "factory", None)
        with self._store_lock:
            with self._lock:
                batch = list(self._unstored)
            if not batch:
                return True
            if factory is None:
                return False
            try:
                with session_scope(factory) as s:
                    webhooks_repo.enqueue(s, batch)
            except StorageError as exc:
                log.warning("webhook messages not stored yet (%d waiting in memory): %s", len(batch), exc)
                return False
            stored = {id(m) for m in batch}  # the batch's objects, alive until here: their ids are theirs
            with self._lock:  # what was stored, not the oldest len(batch): handle() may have dropped some
                self._unstored = collections.deque(m for m in self._unstored if id(m) not in stored)
            return True

    # -- the sender thread ---------------------------------------------------------------
    def _run(self) -> None:
        while not self._stop.is_set():
            wait = POLL_S
            try:
                if self._store() and getattr(self.service, "factory", None) is not None:
                    wait = self._send_due()
                    self._purge()
            except StorageError as exc:
                log.warning("webhooks: the database did not answer (%s); trying again in %g s", exc, POLL_S)
            except Exception:  # a bug must not end delivery for the rest of the run
                log.exception("webhooks: the sender failed; trying again in %g s", POLL_S)
            self._wake.wait(wait)
            self._wake.clear()

    def _send_due(self) -> float:
        """Post every due message, each receiver's in order (a receiver that fails holds its
        later messages back until the retry); the wait until the next one is due."""
        factory = self.service.factory
        claim_s = self.settings.timeout_s * BATCH + 30.0
        down: set[str] = set()
        while not self._stop.is_set():
            now = datetime.now(timezone.utc)
            with session_scope(factory) as s:
                rows = webhooks_repo.claim_due(s, self.sender, now, claim_s, BATCH)
            if not rows:
                break
            for row in rows:
                if self._stop.is_set():
                    with session_scope(factory) as s:
                        webhooks_repo.release(s, row.id)
                elif not self._post(factory, row):
                    down.add(row.url)
            if all(r.url in down for r in rows):
                break  # nothing more can be due before a retry's back-off has passed
        with session_scope(factory) as s:
            nxt = webhooks_repo.next_due(s)
        if nxt is None:
            return POLL_S
        return min(max((nxt - datetime.now(timezone.utc)).total_seconds(), 0.05), POLL_S)

    def _post(self, factory, row) -> bool:
        attempt = row.attempts + 1
        ts = int(time.time())
        body = row.body.encode()
        req = urllib.request.Request(row.url, data=body, method="POST", headers={
            "content-type": "application/json", "user-agent": "mebm-webhooks/1", "webhook-id": row.msg_id,
            "webhook-timestamp": str(ts), "webhook-signature": sign(self.settings.secret, row.msg_id, ts, body)})  # fmt: skip
        status = error = None
        try:
            with urllib.request.urlopen(req, timeout=self.settings.timeout_s) as resp:  # noqa: S310 - configured URLs
                status = resp.status
        except urllib.error.HTTPError as exc:
            status, error = exc.code, f"HTTP {exc.code}"
        except (urllib.error.URLError, OSError, TimeoutError) as exc:
            error = str(getattr(exc, "reason", exc))
        ok = status is not None and 200 <= status < 300
        now = datetime.now(timezone.utc)
        retry_at = None if ok or attempt >= self.settings.max_attempts else now + timedelta(seconds=backoff_s(attempt))
        with session_scope(factory) as s:
            state = webhooks_repo.record_attempt(s, row.id, now, status=status, error=error, delivered=ok,
                                                 retry_at=retry_at)
        self._log(Delivery(row.msg_id, row.url, row.event_type, row.axis_id, attempt, now.isoformat(), status, error, ok))
        if state == webhooks_repo.FAILED:
            self.given_up += 1
            log.warning("webhook %s to %s not delivered after %d attempts: kept as failed (re-queue with "
                        "POST /api/v1/webhooks/messages/retry)", row.msg_id, row.url, attempt)
        return ok

    def _purge(self) -> None:
        if time.monotonic() - self._last_purge < PURGE_EVERY_S:
            return
        self._last_purge = time.monotonic()
        with session_scope(self.service.factory) as s:
            _, dropped = webhooks_repo.purge(s, datetime.now(timezone.utc),
                                             keep_delivered_s=self.settings.keep_delivered_days * 86400.0,
                                             max_failed=self.settings.max_failed)
        if dropped:
            self.purged_failed += dropped
            log.error("webhooks: %d failed message(s) deleted, beyond the %d kept (webhooks.max_failed)",
                      dropped, self.settings.max_failed)

    def _log(self, d: Delivery) -> None:
        with self._lock:
            self.deliveries.append(d)
            if d.delivered:
                self.delivered += 1
            else:
                self.failed += 1

    # -- for the REST API ----------------------------------------------------------------
    def log_entries(self) -> list[dict]:
        with self._lock:
            return [asdict(d) for d in reversed(self.deliveries)]

    @property
    def unstored(self) -> int:
        with self._lock:
            return len(self._unstored)

    def wake(self) -> None:
        """Look for due messages now (e.g. after an admin re-queued failed ones)."""
        self._wake.set()

    def close(self) -> None:
        self.service.events.unsubscribe(self.subscription)
        self._stop.set()
        self._wake.set()
        self._thread.join(self.settings.timeout_s + 5.0)
        with contextlib.suppress(StorageError):
            self._store()  # what the hub handed over last is stored for the next start


def _iso(t: datetime) -> str:
    return t.astimezone(timezone.utc).isoformat().replace("+00:00", "Z")
