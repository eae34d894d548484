"""Dashboard sign-in: one-time sign-in links, server-side sessions, CSRF tokens.

A session is a random id in an HttpOnly, SameSite=Strict cookie; the server keeps the
key it was opened with (so a revoked key ends its sessions at the next request: the key
is checked on every request, through the API's key cache) and the session's CSRF token,
which every form that changes something must send back. Sessions live in the memory of
the one service process: a restart signs everybody out.

A sign-in link carries a random token, never the key: it opens a session once, within
``ttl_s`` of being issued (``make run`` prints one for the demo read key).
"""

from __future__ import annotations

import hmac
import secrets
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field

SESSION_COOKIE = "mebm_session"
PRE_CSRF_COOKIE = "mebm_signin_csrf"  # double-submit token of the sign-in form (no session yet)
ROLE_RANK = {"read": 0, "operate": 1, "admin": 2}  # as the API's keys (api/rest/auth.py)


@dataclass
class Session:
    secret: str  # the API key the session was opened with (never sent back to the browser)
    csrf: str
    created_s: float
    last_seen_s: float


@dataclass
class SignInLinks:
    """One-time sign-in tokens: token -> (key, expiry)."""

    ttl_s: float = 600.0
    clock: Callable[[], float] = time.monotonic
    _tokens: dict[str, tuple[str, float]] = field(default_factory=dict)
    _lock: threading.Lock = field(default_factory=threading.Lock)

    def issue(self, secret: str) -> str:
        token = secrets.token_urlsafe(24)
        with self._lock:
            now = self.clock()
            for t in [t for t, (_, exp) in self._tokens.items() if exp <= now]:
                del self._tokens[t]
            self._tokens[token] = (secret, now + self.ttl_s)
        return token

    def redeem(self, token: str) -> str | None:
        """The key of ``token`` if it is unused and unexpired; the token is spent either way."""
        with self._lock:
            hit = self._tokens.pop(token, None)
        if hit is None or self.clock() >= hit[1]:
            return None
        return hit[0]


@dataclass
class Sessions:
    """Server-side sessions: id -> Session, dropped after ``idle_s`` without a request."""

    idle_s: float = 8 * 3600.0
    max_sessions: int = 10000
    clock: Callable[[], float] = time.monotonic
    _d: dict[str, Session] = field(default_factory=dict)
    _lock: threading.Lock = field(default_factory=threading.Lock)

    def open(self, secret: str) -> tuple[str, Session]:
        sid = secrets.token_urlsafe(32)
        now = self.clock()
        sess = Session(secret=secret, csrf=secrets.token_urlsafe(24), created_s=now, last_seen_s=now)
        with self._lock:
            if len(self._d) >= self.max_sessions:
                oldest = min(self._d, key=lambda k: self._d[k].last_seen_s)
                del self._d[oldest]
            self._d[sid] = sess
        return sid, sess

    def get(self, sid: str | None) -> Session | None:
        if not sid:
            return None
        now = self.clock()
        with self._lock:
            sess = self._d.get(sid)
            if sess is None:
                return None
            if now - sess.last_seen_s > self.idle_s:
                del self._d[sid]
                return None
            sess.last_seen_s = now
            return sess

    def close(self, sid: str | None) -> None:
        with self._lock:
            self._d.pop(sid or "", None)


def same_token(sent: str | None, expected: str | None) -> bool:
    return bool(sent) and bool(expected) and hmac.compare_digest(sent, expected)


class FigureCache:
    """The last ``size`` rendered figures (PNG bytes), least recently used dropped first."""

    def __init__(self, size: int = 64):
        from collections import OrderedDict

        self.size = size
        self._d: OrderedDict[tuple, bytes] = OrderedDict()
        self._lock = threading.Lock()

    def get(self, key: tuple) -> bytes | None:
        with self._lock:
            png = self._d.get(key)
            if png is not None:
                self._d.move_to_end(key)
            return png

    def put(self, key: tuple, png: bytes) -> None:
        with self._lock:
            self._d[key] = png
            self._d.move_to_end(key)
            while len(self._d) > self.size:
                self._d.popitem(last=False)


@dataclass
class UiState:
    """What the dashboard keeps in ``app.state.ui``."""

    links: SignInLinks = field(default_factory=SignInLinks)
    sessions: Sessions = field(default_factory=Sessions)
    figures: FigureCache = field(default_factory=FigureCache)
    gap_started: dict[int, float] = field(default_factory=dict)  # axis id -> when the page started its job (epoch s)
