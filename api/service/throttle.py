"""Token buckets for what a client may repeat, and the failed-authentication throttle
shared by every path that takes a key (REST API, dashboard sign-in, MTConnect agent).

- :class:`TokenBucket`: ``per_minute`` tokens per key, at most ``burst`` saved up.
  Bounded memory: at most ``max_keys`` buckets (the least recently used go first).
- :class:`AuthThrottle`: failed authentications per client address and presented key
  prefix, and per client address. Only failures are counted and refused: a key is
  looked up first, and a valid key is never refused by it. A run of refused failures is
  logged in one line when it starts and then one line per :data:`REPORT_WINDOW_S` with
  the count refused since the last line (and the rest when the run ends or the service
  stops): a flood of failures is a few lines, and none is left uncounted.
"""

from __future__ import annotations

import threading
import time
from collections import OrderedDict

PEER = "mebm.peer"  # the ASGI scope key that keeps the TCP peer (api.rest.proxies)


class TokenBucket:
    """``take(key)`` -> 0 when allowed (a token is used), else seconds until one is free.
    ``blocked(key)`` tells the same without using a token. Thread-safe."""

    def __init__(self, per_minute: float, burst: int, *, max_keys: int = 10000, clock=time.monotonic):
        self.rate_per_s = per_minute / 60.0
        self.burst = max(int(burst), 1)
        self.max_keys = max_keys
        self.clock = clock
        self._buckets: OrderedDict[str, tuple[float, float]] = OrderedDict()  # key -> (tokens, at)
        self._lock = threading.Lock()

    def _level(self, key: str, now: float) -> float:
        tokens, at = self._buckets.get(key, (float(self.burst), now))
        return min(float(self.burst), tokens + (now - at) * self.rate_per_s)

    def _wait_s(self, tokens: float) -> float:
        return (1.0 - tokens) / self.rate_per_s if self.rate_per_s > 0 else 3600.0

    def blocked(self, key: str) -> float:
        with self._lock:
            tokens = self._level(key, self.clock())
            return 0.0 if tokens >= 1.0 else self._wait_s(tokens)

    def take(self, key: str) -> float:
        with self._lock:
            now = self.clock()
            tokens = self._level(key, now)
            if tokens < 1.0:
                self._buckets[key] = (tokens, now)
                self._buckets.move_to_end(key)
                return self._wait_s(tokens)
            self._buckets[key] = (tokens - 1.0, now)
            self._buckets.move_to_end(key)
            while len(self._buckets) > self.max_keys:
                self._buckets.popitem(last=False)
            return 0.0


KEY_PREFIX_CHARS = 9  # as many as a key listing shows (storage: ApiKey.key_prefix)
REPORT_WINDOW_S = 60.0  # a run of refusals is reported, with its count, at most once per this long
SWEEP_S = 1.0  # runs whose window ended are looked for at most this often


class _Run:
    """A run of refused failures of one (address, key prefix): refusals since the last line."""

    __slots__ = ("client", "since", "refused")

    def __init__(self, client: str, since: float):
        self.client, self.since, self.refused = client, since, 0


class AuthThrottle:
    """Failed authentications, counted in two token buckets:

    - per client address and presented key prefix (its first ``KEY_PREFIX_CHARS``
      characters; no key is a prefix of its own): ``per_minute`` / ``burst``. One stale
      script repeating a wrong key empties its own bucket, not the budget of the others
      behind the same address;
    - per client address, over every key: ``address_per_minute`` / ``address_burst``, for
      an address that tries many different keys. A failure already refused by its own
      (address, prefix) bucket is not counted again here.

    ``failed(client, secret)`` is called after a failed lookup only (a valid key is never
    throttled) and returns ``(wait_s, first)``: ``wait_s`` 0 to answer 401, else the
    seconds to put in a 429's Retry-After; ``first`` is True on the first refusal of a
    run of refusals (to log one line per run, not one per attempt). The later refusals of
    a run are counted: :meth:`reports` gives ``(client, refused, span_s)`` for each run
    whose window of ``report_window_s`` ended, or that ended, since it was last asked;
    :meth:`flush` every count not yet reported (when the service stops)."""

    def __init__(self, per_minute: float, burst: int, address_per_minute: float, address_burst: int, *,
                 max_keys: int = 10000, clock=time.monotonic, report_window_s: float = REPORT_WINDOW_S):
        self.per_key = TokenBucket(per_minute, burst, max_keys=max_keys, clock=clock)
        self.per_address = TokenBucket(address_per_minute, address_burst, max_keys=max_keys, clock=clock)
        self.max_keys = max_keys
        self.clock = clock
        self.report_window_s = report_window_s
        self._refusing: OrderedDict[str, _Run] = OrderedDict()  # buckets in a run of refusals
        self._reports: list[tuple[str, int, float]] = []  # (client, refused, span_s) not yet logged
        self._swept = clock()
        self._lock = threading.Lock()

    @staticmethod
    def bucket(client: str, secret: str | None) -> str:
        return f"{client} {(secret or '')[:KEY_PREFIX_CHARS]}"

    def failed(self, client: str, secret: str | None) -> tuple[float, bool]:
        pair = self.bucket(client, secret)
        wait_s = self.per_key.take(pair)
        if wait_s == 0.0:
            wait_s = self.per_address.take(client)
        with self._lock:
            now = self.clock()
            if wait_s == 0.0:
                self._end(self._refusing.pop(pair, None), now)
                return 0.0, False
            run = self._refusing.get(pair)
            first = run is None
            if first:  # the caller logs this one
                self._refusing[pair] = _Run(client, now)
            else:
                run.refused += 1
            self._refusing.move_to_end(pair)
            while len(self._refusing) > self.max_keys:
                self._end(self._refusing.popitem(last=False)[1], now)
            return wait_s, first

    def _end(self, run: _Run | None, now: float) -> None:
        if run is not None and run.refused:
            self._reports.append((run.client, run.refused, now - run.since))
            run.since, run.refused = now, 0

    def reports(self) -> list[tuple[str, int, float]]:
        """``(client, refused, span_s)``: the refusals counted in each run whose report window
        ended, or that ended, since the last call (each count is given once)."""
        with self._lock:
            now = self.clock()
            if now - self._swept >= SWEEP_S:
                self._swept = now
                for run in self._refusing.values():
                    if now - run.since >= self.report_window_s:
                        self._end(run, now)
            out, self._reports = self._reports, []
            return out

    def flush(self) -> list[tuple[str, int, float]]:
        """Every count not yet reported (the service stops)."""
        with self._lock:
            now = self.clock()
            for run in self._refusing.values():
                self._end(run, now)
            out, self._reports = self._reports, []
            return out


def who(request) -> str:
    """The client address for a log line; with the TCP peer when a trusted proxy named
    another client, and the claimed ``X-Forwarded-For`` when there is one (repr'd and cut
    short: it is the sender's text)."""
    client = request.client.host if request.client else "unknown"
    peer = request.scope.get(PEER)
    claim = request.headers.get("x-forwarded-for")
    out = client
    if peer and peer[0] != client:
        out += f" via peer {peer[0]}"
    if claim is not None:
        out += f" (X-Forwarded-For {claim[:100]!r})"
    return out


def failed_authentication(request, secret: str | None, what: str, log) -> float:
    """Counts a failed authentication of ``request`` (a Starlette request) in the app's
    ``state.auth_throttle`` and logs it on ``log`` (never the key); the seconds to wait
    when the failure is to be refused (429), else 0. ``what`` names it in the log line."""
    client = request.client.host if request.client else "unknown"
    throttle = getattr(request.app.state, "auth_throttle", None)
    wait_s, first = throttle.failed(client, secret) if throttle is not None else (0.0, False)
    if wait_s == 0.0:
        log.warning("failed authentication from %s: %s %s (%s)", who(request), request.method, request.url.path, what)
    elif first:  # logged once when the address (and key prefix) gets throttled, not once per attempt
        log.warning("failed authentication from %s: %s %s (%s); throttled for %.0f s",
                    who(request), request.method, request.url.path, what, wait_s)
    if throttle is not None:
        log_refusals(throttle.reports(), log)
    return wait_s


def log_refusals(reports: list[tuple[str, int, float]], log) -> None:
    """One line per run of refused failed authentications, with their count."""
    for client, refused, span_s in reports:
        log.warning("%d more failed authentications from %s refused (throttled) in the last %.0f s",
                    refused, client, span_s)
