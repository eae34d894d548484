"""Dashboard sign-in: one-time sign-in links, sessions, CSRF tokens.

A session is a random token in an HttpOnly, SameSite=Strict cookie; the database keeps
its SHA-256, its key and its expiry (storage/db/ui_sessions_repo.py), so a restart signs
nobody out and several ``serve`` processes on one database share the sessions. The
key's role and revocation are read with the session on every request: a revoked key
ends its sessions at once. The CSRF token every changing form sends back is derived
from the session token (an HMAC), so it needs no storage and is unknown to anyone who
cannot read the cookie.

A sign-in link carries another random token, never the key: it is good once, within
``link_ttl_s`` of being issued (``make run`` prints one for the demo read key). Opening
it (GET) only shows a button; the POST of that button spends it, so a link preview
(a chat or mail scanner fetching the URL) does not use it up.
"""

from __future__ import annotations

import hashlib
import hmac
from collections.abc import Callable
from dataclasses import dataclass, field
from datetime import datetime

from storage.db import KeyRecord, config_repo, session_scope, ui_sessions_repo, utcnow

SESSION_COOKIE = "mebm_session"
PRE_CSRF_COOKIE = "mebm_signin_csrf"  # double-submit token of the sign-in forms (no session yet)
ROLE_RANK = {"read": 0, "operate": 1, "admin": 2}  # as the API's keys (api/rest/auth.py)


def csrf_of(token: str) -> str:
    return hmac.new(token.encode("utf-8"), b"mebm-ui-csrf", hashlib.sha256).hexdigest()[:40]


@dataclass(frozen=True)
class Session:
    token: str  # the cookie's value (only its hash is stored)
    key: KeyRecord
    expires_at: datetime

    @property
    def csrf(self) -> str:
        return csrf_of(self.token)


@dataclass
class UiSessions:
    """Sessions and sign-in links in the database of ``service`` (set by ``api.ui.install``)."""

    service: object = None
    link_ttl_s: float = 600.0
    idle_s: float = 8 * 3600.0
    clock: Callable[[], datetime] = utcnow

    @property
    def factory(self):
        return self.service.factory  # opened when the service starts

    def issue_link(self, secret: str) -> str:
        """A one-time sign-in token for the key whose secret is ``secret``."""
        with session_scope(self.factory) as s:
            rec = config_repo.authenticate(s, secret)
            if rec is None:
                from core.errors import InputError

                raise InputError("no live key with this secret: no sign-in link for it")
            return ui_sessions_repo.issue_link(s, rec.id, self.clock(), self.link_ttl_s)

    def peek_link(self, token: str) -> KeyRecord | None:
        with session_scope(self.factory) as s:
            return ui_sessions_repo.peek_link(s, token, self.clock())

    def redeem_link(self, token: str) -> Session | None:
        with session_scope(self.factory) as s:
            hit = ui_sessions_repo.redeem_link(s, token, self.clock(), self.idle_s)
        return None if hit is None else self.get(hit[0])

    def open(self, key: KeyRecord) -> Session:
        with session_scope(self.factory) as s:
            token = ui_sessions_repo.open_session(s, key.id, self.clock(), self.idle_s)
        return Session(token, key, self.clock())

    def get(self, token: str | None) -> Session | None:
        if not token:
            return None
        with session_scope(self.factory) as s:
            rec = ui_sessions_repo.get_session(s, token, self.clock(), self.idle_s)
        return None if rec is None else Session(token, rec.key, rec.expires_at)

    def close(self, token: str | None) -> None:
        with session_scope(self.factory) as s:
            ui_sessions_repo.close_session(s, token)


def same_token(sent: str | None, expected: str | None) -> bool:
    """Whether a form's CSRF token is the expected one, in constant time. Compared as
    UTF-8 bytes: ``hmac.compare_digest`` refuses str with non-ASCII characters (a
    TypeError, a 500), and a token sent by anyone may hold any."""
    if not sent or not expected:
        return False
    return hmac.compare_digest(sent.encode("utf-8", "surrogatepass"), expected.encode("utf-8", "surrogatepass"))


@dataclass
class UiState:
    """What the dashboard keeps in ``app.state.ui``."""

    sessions: UiSessions = field(default_factory=UiSessions)
