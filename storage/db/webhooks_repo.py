"""Repository: webhook messages kept until delivered (table ``webhook_messages``).

A message is stored before it is sent, one row per receiver URL, so a stop, a crash or a
receiver outage longer than the retries never loses it. A sender claims due rows for a
while (``claimed_until``) before it posts them; a row whose claim ran out (its sender died)
is due again for any sender on the database, so delivery is at least once, with the same
``webhook-id`` on every try for the receiver to drop a repeat. Rows that used every attempt
stay ``failed`` until an admin re-queues them; delivered rows are purged after a while.
"""

from __future__ import annotations

from dataclasses import dataclass
from datetime import datetime, timedelta

from sqlalchemy import and_, delete, func, or_, select, update
from sqlalchemy.orm import Session

from storage.db.models import WebhookMessage
from storage.db.records import as_utc

PENDING, DELIVERED, FAILED = "pending", "delivered", "failed"
STATES = (PENDING, DELIVERED, FAILED)


@dataclass(frozen=True)
class NewMessage:
    msg_id: str
    url: str
    event_type: str
    axis_id: int
    body: str
    created_at: datetime


@dataclass(frozen=True)
class MessageRecord(NewMessage):
    """A stored message: what was enqueued, its row id and its delivery so far."""

    id: int
    state: str
    attempts: int
    next_at: datetime
    last_status: int | None
    last_error: str | None
    done_at: datetime | None


def _record(m: WebhookMessage) -> MessageRecord:
    return MessageRecord(id=m.id, msg_id=m.msg_id, url=m.url, event_type=m.event_type, axis_id=m.axis_id,
                         body=m.body, created_at=as_utc(m.created_at), state=m.state, attempts=m.attempts,
                         next_at=as_utc(m.next_at), last_status=m.last_status, last_error=m.last_error,
                         done_at=as_utc(m.done_at))  # fmt: skip


def enqueue(s: Session, messages: list[NewMessage]) -> None:
    """Store ``messages`` as pending, due at once."""
    for m in messages:
        s.add(WebhookMessage(msg_id=m.msg_id, url=m.url, event_type=m.event_type, axis_id=m.axis_id, body=m.body,
                             created_at=m.created_at, state=PENDING, attempts=0, next_at=m.created_at))
    s.flush()


def _due(now: datetime):
    return and_(WebhookMessage.state == PENDING, WebhookMessage.next_at <= now,
                or_(WebhookMessage.claimed_until.is_(None), WebhookMessage.claimed_until < now))


def claim_due(s: Session, sender: str, now: datetime, claim_s: float, limit: int = 20) -> list[MessageRecord]:
    """The due messages that head their receiver's queue (the oldest pending one per URL:
    a receiver gets its messages in order, a raised alert never after its clearing), up to
    ``limit``, claimed by ``sender`` for ``claim_s``. A row another sender claimed in
    between is left to it (the claim is a conditional update: of two senders only the one
    whose update hit the row has it)."""
    ids = s.scalars(select(WebhookMessage.id).where(WebhookMessage.id.in_(_heads()), _due(now))
                    .order_by(WebhookMessage.id).limit(limit)).all()
    until = now + timedelta(seconds=claim_s)
    mine = []
    for i in ids:
        hit = s.execute(update(WebhookMessage).where(WebhookMessage.id == i, _due(now))
                        .values(claimed_by=sender, claimed_until=until)).rowcount
        if hit == 1:
            mine.append(i)
    s.flush()
    if not mine:
        return []
    rows = s.scalars(select(WebhookMessage).where(WebhookMessage.id.in_(mine)).order_by(WebhookMessage.id)).all()
    return [_record(m) for m in rows]


def record_attempt(s: Session, message_id: int, now: datetime, *, status: int | None, error: str | None,
                   delivered: bool, retry_at: datetime | None) -> str:
    """One attempt's outcome: ``delivered``, else pending again at ``retry_at``, else (no
    ``retry_at``: every attempt used) ``failed``. Returns the row's new state."""
    state = DELIVERED if delivered else (PENDING if retry_at is not None else FAILED)
    s.execute(update(WebhookMessage).where(WebhookMessage.id == message_id).values(
        attempts=WebhookMessage.attempts + 1, last_status=status, last_error=error, state=state,
        next_at=retry_at if retry_at is not None else now, done_at=None if state == PENDING else now,
        claimed_by=None, claimed_until=None))  # fmt: skip
    return state


def release(s: Session, message_id: int) -> None:
    """Give a claimed message back unsent, without counting an attempt."""
    s.execute(update(WebhookMessage).where(WebhookMessage.id == message_id)
              .values(claimed_by=None, claimed_until=None))


def _heads():
    """The oldest pending message of each receiver: the only one that may be sent."""
    return select(func.min(WebhookMessage.id)).where(WebhookMessage.state == PENDING).group_by(WebhookMessage.url)


def next_due(s: Session) -> datetime | None:
    """When a sender should look next: the earliest time a receiver's head becomes
    claimable (its ``next_at``, or the end of another sender's claim on it); None when none
    is pending. The messages queued behind a head are not due before it, whatever their own
    ``next_at`` (one row per receiver is read: the heads)."""
    rows = s.execute(select(WebhookMessage.next_at, WebhookMessage.claimed_until)
                     .where(WebhookMessage.id.in_(_heads()))).all()
    times = [max(as_utc(n), as_utc(c)) if c is not None else as_utc(n) for n, c in rows]
    return min(times, default=None)


def counts(s: Session) -> dict[str, int]:
    rows = s.execute(select(WebhookMessage.state, func.count()).group_by(WebhookMessage.state)).all()
    out = dict.fromkeys(STATES, 0)
    out.update({st: n for st, n in rows})
    return out


def list_messages(s: Session, *, state: str | None = None, limit: int = 100) -> list[MessageRecord]:
    """Messages, newest first, of one state or all."""
    q = select(WebhookMessage).order_by(WebhookMessage.id.desc()).limit(limit)
    if state is not None:
        q = q.where(WebhookMessage.state == state)
    return [_record(m) for m in s.scalars(q).all()]


def requeue_failed(s: Session, now: datetime) -> int:
    """Every failed message pending again, due now, with its attempts counted afresh.
    Returns how many."""
    return s.execute(update(WebhookMessage).where(WebhookMessage.state == FAILED).values(
        state=PENDING, attempts=0, next_at=now, done_at=None, claimed_by=None, claimed_until=None)).rowcount


def purge(s: Session, now: datetime, *, keep_delivered_s: float, max_failed: int) -> tuple[int, int]:
    """Delete delivered messages older than ``keep_delivered_s`` and, beyond ``max_failed``
    failed ones, the oldest failed. Returns (delivered deleted, failed deleted)."""
    gone = s.execute(delete(WebhookMessage).where(
        WebhookMessage.state == DELIVERED,
        WebhookMessage.done_at < now - timedelta(seconds=keep_delivered_s))).rowcount
    n_failed = s.scalar(select(func.count()).where(WebhookMessage.state == FAILED)) or 0
    dropped = 0
    if n_failed > max_failed:
        old = s.scalars(select(WebhookMessage.id).where(WebhookMessage.state == FAILED)
                        .order_by(WebhookMessage.id).limit(n_failed - max_failed)).all()
        dropped = s.execute(delete(WebhookMessage).where(WebhookMessage.id.in_(old))).rowcount
    return gone, dropped
