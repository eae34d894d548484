"""Repository: the dashboard's sessions and one-time sign-in links (table ``ui_sessions``).

Both are random tokens of which only the SHA-256 is stored, bound to an access key: a
restart keeps them and every ``serve`` process on the database sees them. A session
ends when it idles past its expiry (slid forward as it is used), when it is signed
out, or when its key is revoked (:func:`storage.db.config_repo.revoke_key` marks the
key's sessions; a lookup also checks the key itself). A link is spent by deleting its
row: of two processes redeeming one link, only the one whose delete hit a row wins.
"""

from __future__ import annotations

import hashlib
import secrets
from dataclasses import dataclass
from datetime import datetime, timedelta

from sqlalchemy import delete, select, update
from sqlalchemy.orm import Session

from core.errors import InputError
from storage.db.models import ApiKey, UiSession
from storage.db.records import KeyRecord, as_utc

SESSION, LINK = "session", "link"
TOUCH_EVERY_S = 60.0  # a polled page writes the sliding expiry at most once a minute


def _sha(token: str) -> str:
    return hashlib.sha256(token.encode("utf-8")).hexdigest()


def _key(k: ApiKey) -> KeyRecord:
    return KeyRecord(id=k.id, name=k.name, role=k.role, key_prefix=k.key_prefix,
                     created_at=as_utc(k.created_at), revoked_at=as_utc(k.revoked_at))


@dataclass(frozen=True)
class UiSessionRecord:
    id: int
    key: KeyRecord
    created_at: datetime
    expires_at: datetime


def _new(s: Session, kind: str, key_id: int, now: datetime, ttl_s: float) -> str:
    token = secrets.token_urlsafe(32)
    s.add(UiSession(kind=kind, token_sha256=_sha(token), key_id=key_id, created_at=now, last_seen_at=now,
                    expires_at=now + timedelta(seconds=ttl_s)))
    s.flush()
    return token


def issue_link(s: Session, key_id: int, now: datetime, ttl_s: float) -> str:
    """A one-time sign-in token for the (live) key ``key_id``, valid ``ttl_s``."""
    k = s.get(ApiKey, key_id)
    if k is None or k.revoked_at is not None:
        raise InputError(f"key id {key_id} is unknown or revoked: no sign-in link for it")
    purge(s, now)
    return _new(s, LINK, key_id, now, ttl_s)


def _live(s: Session, kind: str, token: str, now: datetime) -> tuple[UiSession, ApiKey] | None:
    if not token:
        return None
    row = s.execute(select(UiSession, ApiKey).join(ApiKey, ApiKey.id == UiSession.key_id)
                    .where(UiSession.token_sha256 == _sha(token), UiSession.kind == kind)).first()
    if row is None:
        return None
    u, k = row
    if u.revoked_at is not None or k.revoked_at is not None or as_utc(u.expires_at) <= now:
        return None
    return u, k


def peek_link(s: Session, token: str, now: datetime) -> KeyRecord | None:
    """The key of an unused, unexpired link, without spending it (a link preview)."""
    hit = _live(s, LINK, token, now)
    return None if hit is None else _key(hit[1])


def redeem_link(s: Session, token: str, now: datetime, idle_s: float) -> tuple[str, KeyRecord] | None:
    """Spend a link: a new session token and its key, or None (used, expired, revoked key).
    The link is spent whether or not it was still good."""
    if not token:
        return None
    hit = _live(s, LINK, token, now)
    gone = s.execute(delete(UiSession).where(UiSession.token_sha256 == _sha(token), UiSession.kind == LINK))
    if hit is None or gone.rowcount != 1:  # another process spent it first
        return None
    return open_session(s, hit[1].id, now, idle_s), _key(hit[1])


def open_session(s: Session, key_id: int, now: datetime, idle_s: float) -> str:
    purge(s, now)
    return _new(s, SESSION, key_id, now, idle_s)


def get_session(s: Session, token: str | None, now: datetime, idle_s: float) -> UiSessionRecord | None:
    """The live session of ``token`` (its expiry slid forward), or None."""
    hit = _live(s, SESSION, token or "", now)
    if hit is None:
        return None
    u, k = hit
    if (now - as_utc(u.last_seen_at)).total_seconds() >= TOUCH_EVERY_S:
        u.last_seen_at, u.expires_at = now, now + timedelta(seconds=idle_s)
        s.flush()
    return UiSessionRecord(id=u.id, key=_key(k), created_at=as_utc(u.created_at), expires_at=as_utc(u.expires_at))


def close_session(s: Session, token: str | None) -> None:
    if token:
        s.execute(delete(UiSession).where(UiSession.token_sha256 == _sha(token), UiSession.kind == SESSION))


def revoke_for_key(s: Session, key_id: int, now: datetime) -> int:
    """End every session and link of a key (it was revoked); how many."""
    res = s.execute(update(UiSession).where(UiSession.key_id == key_id, UiSession.revoked_at.is_(None))
                    .values(revoked_at=now))
    return res.rowcount


def purge(s: Session, now: datetime) -> int:
    """Delete expired and revoked rows (called when a session or link is made)."""
    res = s.execute(delete(UiSession).where((UiSession.expires_at <= now) | UiSession.revoked_at.is_not(None)))
    return res.rowcount
